//! The silhouette term of the fitting (SPEC 5.1; issue 17, item 2): the fitted surface
//! projected into each camera should cover its mask and nothing else.
//!
//! A carved hull is the masks' cones intersected on a voxel grid: its surface is a voxel
//! away from where the masks put it, and the fit inherits that. The masks themselves are
//! exact to a pixel (a few millimetres where a voxel is a couple of centimetres). Each
//! camera's mask comes as its signed distance $S$ in pixels (positive outside, zero on the
//! outline; computed once per frame by an exact distance transform). At an iterate, every
//! surface node $x_p$ is projected into every camera, $q = \pi(x_p)$:
//!
//! - a node projecting outside the mask ($S(q) > $ [`OUTSIDE_PIXELS`]), by no more than its
//!   support $d_p$ projected, is pushed in;
//! - a *rim* node (its normal across the camera's ray, $|n_p \cdot r| < $ [`RIM_COSINE`],
//!   and its projected normal along the mask's outward gradient) inside the mask but within
//!   [`RIM_BAND_PIXELS`] of the outline is pulled out to it: the model's outline there lies
//!   inside the mask's and leaves mask pixels uncovered.
//!
//! Either way the image step $\Delta q = -S(q)\,\nabla S / |\nabla S|$ is lifted to 3-D in the
//! plane normal to the ray, $\Delta = J^+ \Delta q$ with $J$ the $2 \times 3$ Jacobian of the
//! projection at $x_p$ (by differences, the lens distortion and skew included; its null
//! space is the ray), and the node is pulled to $x_p + \Delta$ with the metric
//! $w\, m m^\top$, $m = \Delta / |\Delta|$: only across the outline, free to slide along it
//! and along the ray. The pull is one per node and camera, of weight $w$ each, as a surface
//! association's.

use rayon::prelude::*;

use super::coverage::Pull;
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::linalg::{dot, unit};

/// A node projecting farther than this (pixels) outside a mask is pushed in (half a pixel:
/// the outline's own rounding).
pub const OUTSIDE_PIXELS: f64 = 0.5;
/// A surface node is on a camera's rim when its normal's cosine with the ray is below this.
pub const RIM_COSINE: f64 = 0.3;
/// A rim node inside a mask is drawn out to the outline only from this close (pixels): a
/// node with its normal across the ray is on the model's outline only where nothing of
/// the model lies beyond it, which the normal alone does not tell (the side of a box seen
/// at a grazing angle is all rim); farther misses are the coverage term's (measured on the
/// fast-motion capture, seed 1: drawing rim nodes out from their projected support away,
/// 20-40 pixels, raised the fit's error from 1.11 to 1.22 of the hull's).
pub const RIM_BAND_PIXELS: f64 = 2.0;
/// The exponent bits of a float64: all set for infinities and NaN.
const EXPONENT: u64 = 0x7ff0_0000_0000_0000;
/// Step of the finite differences of the projection, as a fraction of the node's support.
const JACOBIAN_STEP: f64 = 1e-4;

/// One camera and its mask's signed distance (borrowed: eight masks of 1024 x 768 are 50
/// MB of float64, and copying them cost a fifth of a frame's refinement).
#[derive(Debug, Clone)]
pub struct SilhouetteView<'a> {
    camera: Camera,
    /// $S$ in pixels over the window, row-major, positive outside the mask.
    signed: &'a [f64],
    window: Window,
}

/// The part of a camera's image where a view's distances are given exactly: the term reads
/// only the band around the mask its nodes can reach (`python/elastocap/elastic/silhouette.py`,
/// `term_margins`), a person fills a few percent of a frame, and outside the window the
/// distance to the mask's bounding box less half a pixel stands in (a lower bound, at least
/// the window's margin).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Window {
    /// First row and column of the window.
    pub origin: [usize; 2],
    /// Rows and columns of the window.
    pub size: [usize; 2],
    /// The mask's bounding box: first and last row, first and last column.
    pub bounds: [usize; 4],
}

impl<'a> SilhouetteView<'a> {
    /// A view from `camera` (the rig's camera number `index`) and the signed distance
    /// `signed` of its mask (pixels, row-major over `width` x `height` pixels, positive
    /// outside the mask).
    ///
    /// # Errors
    /// [`Error::MaskSize`] when the image is not the camera's, [`Error::NonFinite`] for a
    /// non-finite distance.
    pub fn new(
        camera: Camera,
        index: usize,
        signed: &'a [f64],
        width: usize,
        height: usize,
    ) -> Result<Self> {
        if width != camera.width || height != camera.height {
            return Err(Error::MaskSize {
                camera: index,
                got_width: width,
                got_height: height,
                width: camera.width,
                height: camera.height,
            });
        }
        let window = Window {
            origin: [0, 0],
            size: [height, width],
            bounds: [0, height.saturating_sub(1), 0, width.saturating_sub(1)],
        };
        Self::windowed(camera, index, signed, window)
    }

    /// [`Self::new`] with the distances given over `window` only (`signed` row-major over
    /// its rows and columns).
    ///
    /// # Errors
    /// [`Error::MaskSize`] when the window or the mask's bounding box does not lie in the
    /// camera's image or `signed` does not fill the window, [`Error::NonFinite`] for a
    /// non-finite distance.
    pub fn windowed(
        camera: Camera,
        index: usize,
        signed: &'a [f64],
        window: Window,
    ) -> Result<Self> {
        let ([row, column], [rows, columns]) = (window.origin, window.size);
        let [top, bottom, left, right] = window.bounds;
        let fits = row + rows <= camera.height
            && column + columns <= camera.width
            && signed.len() == rows * columns
            && top <= bottom
            && bottom < camera.height
            && left <= right
            && right < camera.width;
        if !fits {
            return Err(Error::MaskSize {
                camera: index,
                got_width: columns,
                got_height: rows,
                width: camera.width,
                height: camera.height,
            });
        }
        // A branch-free pass over each block (vectorised), the exact place only on failure:
        // an early-exit scan of 6 million values cost 6 ms per camera.
        let bad = |v: &f64| v.to_bits() & EXPONENT == EXPONENT;
        let any_bad = signed
            .chunks(4096)
            .any(|block| block.iter().fold(false, |found, v| found | bad(v)));
        if let Some(row) = any_bad.then(|| signed.iter().position(bad)).flatten() {
            return Err(Error::NonFinite {
                argument: "silhouette signed distance",
                row,
            });
        }
        Ok(Self {
            camera,
            signed,
            window,
        })
    }

    /// $S$ at pixel centre (`column`, `row`) of the image.
    fn at_pixel(&self, column: usize, row: usize) -> f64 {
        let ([r0, c0], [rows, columns]) = (self.window.origin, self.window.size);
        if (r0..r0 + rows).contains(&row) && (c0..c0 + columns).contains(&column) {
            return self.signed[(row - r0) * columns + (column - c0)];
        }
        // The same operations as numpy's in `signed_mask_distance`, so a windowed view
        // reads what the whole image's would, to the bit.
        let [top, bottom, left, right] = self.window.bounds.map(|b| b as f64);
        let (r, c) = (row as f64, column as f64);
        let dr = (top - r).max(r - bottom).max(0.0);
        let dc = (left - c).max(c - right).max(0.0);
        (dr * dr + dc * dc).sqrt() - 0.5
    }

    /// $S$ and its gradient at pixel `q` (bilinear; central differences one pixel apart),
    /// or `None` outside the image.
    fn sample(&self, q: [f64; 2]) -> Option<(f64, [f64; 2])> {
        let at = |u: f64, v: f64| -> Option<f64> {
            let (w, h) = (self.camera.width, self.camera.height);
            if !(u >= 0.0 && v >= 0.0 && u <= (w - 1) as f64 && v <= (h - 1) as f64) {
                return None;
            }
            let (i, j) = (
                (u as usize).min(w.saturating_sub(2)),
                (v as usize).min(h.saturating_sub(2)),
            );
            let (fu, fv) = (u - i as f64, v - j as f64);
            let s = |c: usize, r: usize| self.at_pixel(c.min(w - 1), r.min(h - 1));
            Some(
                (1.0 - fv) * ((1.0 - fu) * s(i, j) + fu * s(i + 1, j))
                    + fv * ((1.0 - fu) * s(i, j + 1) + fu * s(i + 1, j + 1)),
            )
        };
        let value = at(q[0], q[1])?;
        let gu = (at(q[0] + 0.5, q[1])? - at(q[0] - 0.5, q[1])?) * 1.0;
        let gv = (at(q[0], q[1] + 0.5)? - at(q[0], q[1] - 0.5)?) * 1.0;
        Some((value, [gu, gv]))
    }
}

/// The projection's Jacobian at `x` by forward differences of step `h`, rows u and v.
fn jacobian(camera: &Camera, x: &[f64; 3], h: f64) -> Option<([f64; 2], [[f64; 3]; 2])> {
    let q = camera.project(x)?;
    let mut j = [[0.0; 3]; 2];
    for axis in 0..3 {
        let mut moved = *x;
        moved[axis] += h;
        let p = camera.project(&moved)?;
        j[0][axis] = (p[0] - q[0]) / h;
        j[1][axis] = (p[1] - q[1]) / h;
    }
    Some((q, j))
}

/// $J^+ d$ for a full-rank $2 \times 3$ `j`: $J^\top (J J^\top)^{-1} d$.
fn lift(j: &[[f64; 3]; 2], d: [f64; 2]) -> Option<[f64; 3]> {
    let (a, b, c) = (dot(&j[0], &j[0]), dot(&j[0], &j[1]), dot(&j[1], &j[1]));
    let det = a * c - b * b;
    if !(det > 0.0) {
        return None;
    }
    let y = [(c * d[0] - b * d[1]) / det, (a * d[1] - b * d[0]) / det];
    Some(std::array::from_fn(|k| j[0][k] * y[0] + j[1][k] * y[1]))
}

/// The silhouette term at one iterate.
#[derive(Debug, Clone, Default)]
pub struct Silhouette<const D: usize> {
    /// One pull per node and camera that acted.
    pub pulls: Vec<Pull<D>>,
    /// Pulls pushing a node back into a mask.
    pub outside: usize,
    /// Pulls drawing a rim node out to a mask's outline.
    pub rim: usize,
    /// The term at the iterate, $\sum w |\Delta|^2$.
    pub energy: f64,
}

/// The pulls of `views` on the surface nodes at `positions` (unit outward `normals`,
/// supports `support`) with weight `weight` per node and camera; none in 2-D.
pub fn silhouette<const D: usize>(
    views: &[SilhouetteView<'_>],
    positions: &[[f64; D]],
    normals: &[[f64; D]],
    support: &[f64],
    weight: f64,
) -> Silhouette<D> {
    if D != 3 || views.is_empty() || !(weight > 0.0) {
        return Silhouette::default();
    }
    // (pull, outside?) per node and view.
    let found: Vec<(Pull<D>, bool)> = (0..positions.len())
        .into_par_iter()
        .flat_map_iter(|p| {
            let x: [f64; 3] = std::array::from_fn(|a| positions[p][a]);
            let n: [f64; 3] = std::array::from_fn(|a| normals[p][a]);
            views.iter().filter_map(move |view| {
                let (q, j) = jacobian(&view.camera, &x, JACOBIAN_STEP * support[p])?;
                let (s, g) = view.sample(q)?;
                let norm = (g[0] * g[0] + g[1] * g[1]).sqrt();
                if !(norm > 0.0) {
                    return None;
                }
                let outward = [g[0] / norm, g[1] / norm];
                let outside = s > OUTSIDE_PIXELS;
                // A node farther outside than its projected support is not the outline's
                // rounding but a part out of place: the nearest mask pixel may be another
                // part's (a leg pushed into its neighbour's silhouette), and the surface
                // and coverage terms, with their invalidation, move it (horse gallop without
                // this bound: mean drift 1.81% -> 4.61% of the diagonal).
                let reach = support[p] * dot(&j[0], &j[0]).max(dot(&j[1], &j[1])).sqrt();
                if outside && s > reach {
                    return None;
                }
                if !outside {
                    // The ray is J's null space: J's rows crossed.
                    let ray = unit(&[
                        j[0][1] * j[1][2] - j[0][2] * j[1][1],
                        j[0][2] * j[1][0] - j[0][0] * j[1][2],
                        j[0][0] * j[1][1] - j[0][1] * j[1][0],
                    ]);
                    let projected = [dot(&j[0], &n), dot(&j[1], &n)];
                    let rim = dot(&ray, &n).abs() < RIM_COSINE
                        && projected[0] * outward[0] + projected[1] * outward[1] > 0.0
                        && -s < RIM_BAND_PIXELS
                        && s < -OUTSIDE_PIXELS;
                    if !rim {
                        return None;
                    }
                }
                let delta = lift(&j, [-s * outward[0], -s * outward[1]])?;
                let length = dot(&delta, &delta).sqrt();
                if !(length > 0.0) {
                    return None;
                }
                let m: [f64; 3] = std::array::from_fn(|a| delta[a] / length);
                let pull = Pull {
                    node: p,
                    target: std::array::from_fn(|a| x[a] + delta[a]),
                    weight: std::array::from_fn(|r| std::array::from_fn(|c| weight * m[r] * m[c])),
                };
                Some((pull, outside))
            })
        })
        .collect();
    let outside = found.iter().filter(|(_, o)| *o).count();
    let rim = found.len() - outside;
    let energy = found
        .iter()
        .map(|(pull, _)| {
            let d: [f64; D] = std::array::from_fn(|a| positions[pull.node][a] - pull.target[a]);
            (0..D)
                .map(|r| (0..D).map(|c| d[r] * pull.weight[r][c] * d[c]).sum::<f64>())
                .sum::<f64>()
        })
        .sum();
    Silhouette {
        pulls: found.into_iter().map(|(pull, _)| pull).collect(),
        outside,
        rim,
        energy,
    }
}
