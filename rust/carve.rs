//! Visual hulls by voxel carving (SPEC 2), hierarchical and parallel.
//!
//! A voxel survives when at most `tolerance` of the cameras that see it find its footprint
//! background. Footprints are tested in O(1) with a summed-area table per silhouette: the
//! box of a block of voxels projects inside the bounding box of its 8 projected corners
//! (widened by a pixel for lens distortion), and that rectangle either holds no foreground
//! pixel (the camera rejects the whole block), only foreground (it accepts the whole block),
//! or both, in which case the block is split in eight and only the undecided cameras are
//! asked again. So the work follows the surface of the hull, not its volume.
//!
//! At the voxel level the footprint is either `Conservative` (the corner rectangle: never
//! removes a voxel that the object touches) or `Center` (the pixel under the voxel centre).

use rayon::prelude::*;

use crate::camera::Camera;
use crate::error::{Error, Result};

/// The footprint test at the finest level.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Footprint {
    /// A voxel is background for a camera when the pixel under its centre is.
    Center,
    /// A voxel is background for a camera only when its whole projected box is.
    Conservative,
}

/// A silhouette as a summed-area table: foreground counts of any rectangle in O(1).
pub struct Silhouette {
    width: usize,
    height: usize,
    /// `(height + 1) x (width + 1)`: `sat[y][x]` counts foreground in rows `< y`, columns `< x`.
    sat: Vec<u32>,
}

impl Silhouette {
    /// Builds the table of a row-major `(height, width)` mask (non-zero = foreground).
    pub fn new(mask: &[u8], width: usize, height: usize) -> Self {
        let w1 = width + 1;
        let mut sat = vec![0u32; (height + 1) * w1];
        for y in 0..height {
            let mut row = 0u32;
            for x in 0..width {
                row += (mask[y * width + x] != 0) as u32;
                sat[(y + 1) * w1 + x + 1] = sat[y * w1 + x + 1] + row;
            }
        }
        Silhouette { width, height, sat }
    }

    /// Foreground pixels in columns `x0..=x1`, rows `y0..=y1` (inside the image).
    #[inline]
    fn count(&self, x0: usize, y0: usize, x1: usize, y1: usize) -> u32 {
        let w1 = self.width + 1;
        let at = |x: usize, y: usize| self.sat[y * w1 + x];
        at(x1 + 1, y1 + 1) + at(x0, y0) - at(x0, y1 + 1) - at(x1 + 1, y0)
    }
}

/// A borrowed row-major `(height, width)` mask, non-zero = foreground.
#[derive(Debug, Clone, Copy)]
pub struct Mask<'a> {
    /// `height * width` pixels, row-major.
    pub pixels: &'a [u8],
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
}

/// [`carve`] from masks: their summed-area tables are built in parallel first.
///
/// # Errors
/// [`Error::WrongLength`] for a mask whose pixels are not `height * width`; as [`carve`].
pub fn carve_masks(
    cameras: &[Camera],
    masks: &[Mask<'_>],
    grid: GridSpec,
    tolerance: usize,
    footprint: Footprint,
) -> Result<Vec<bool>> {
    for mask in masks {
        let expected = mask.width.saturating_mul(mask.height);
        if mask.pixels.len() != expected {
            return Err(Error::WrongLength {
                argument: "masks",
                expected,
                got: mask.pixels.len(),
            });
        }
    }
    let silhouettes: Vec<Silhouette> = masks
        .par_iter()
        .map(|m| Silhouette::new(m.pixels, m.width, m.height))
        .collect();
    carve(cameras, &silhouettes, grid, tolerance, footprint)
}

/// What one camera says about a box of voxels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum View {
    /// The box projects into the image onto background only: reject it all.
    Empty,
    /// The box projects into the image onto foreground only: accept it all.
    Full,
    /// The box projects outside the image: this camera does not see it.
    Outside,
    /// Mixed, partly outside the image, or partly behind the camera: look closer.
    Unsure,
}

/// Where the voxels are: voxel `[i, j, k]` is centred at `origin + spacing * (i, j, k)`.
#[derive(Debug, Clone, Copy)]
pub struct GridSpec {
    /// Centre of voxel `[0, 0, 0]`, world units.
    pub origin: [f64; 3],
    /// Voxel edge, world units.
    pub spacing: f64,
    /// Voxels per axis.
    pub shape: [usize; 3],
}

/// Voxels per side of the blocks the carving starts from (a power of two).
const TOP_BLOCK: usize = 16;

struct Carver<'a> {
    cameras: &'a [Camera],
    silhouettes: &'a [Silhouette],
    grid: GridSpec,
    tolerance: usize,
    footprint: Footprint,
}

/// Carves the visual hull: `occupancy[(i * ny + j) * nz + k]` is true for kept voxels.
///
/// # Errors
/// [`Error::GridShape`] for an empty grid or a bad spacing, [`Error::MaskSize`] when a
/// silhouette does not match its camera's image, [`Error::Empty`] without cameras.
pub fn carve(
    cameras: &[Camera],
    silhouettes: &[Silhouette],
    grid: GridSpec,
    tolerance: usize,
    footprint: Footprint,
) -> Result<Vec<bool>> {
    if cameras.is_empty() {
        return Err(Error::Empty {
            argument: "cameras",
            needed: 1,
        });
    }
    for (c, (cam, sil)) in cameras.iter().zip(silhouettes).enumerate() {
        if cam.width != sil.width || cam.height != sil.height || cameras.len() != silhouettes.len()
        {
            return Err(Error::MaskSize {
                camera: c,
                got_width: sil.width,
                got_height: sil.height,
                width: cam.width,
                height: cam.height,
            });
        }
    }
    let [nx, ny, nz] = grid.shape;
    let voxels = nx.checked_mul(ny).and_then(|v| v.checked_mul(nz));
    if voxels.is_none_or(|v| v == 0)
        || !(grid.spacing.is_finite() && grid.spacing > 0.0)
        || grid.origin.iter().any(|o| !o.is_finite())
    {
        return Err(Error::GridShape {
            voxels: voxels.unwrap_or(0),
            shape: grid.shape,
            spacing: [grid.spacing; 3],
        });
    }
    let carver = Carver {
        cameras,
        silhouettes,
        grid,
        tolerance,
        footprint,
    };
    let mut occupancy = vec![false; nx * ny * nz];
    // Slabs of TOP_BLOCK x-planes are contiguous: each task owns one.
    occupancy
        .par_chunks_mut(TOP_BLOCK * ny * nz)
        .enumerate()
        .for_each(|(slab, out)| {
            let i0 = slab * TOP_BLOCK;
            let mut views = vec![View::Unsure; cameras.len()];
            for j0 in (0..ny).step_by(TOP_BLOCK) {
                for k0 in (0..nz).step_by(TOP_BLOCK) {
                    views.fill(View::Unsure);
                    carver.decide([i0, j0, k0], TOP_BLOCK, &views, i0, out);
                }
            }
        });
    Ok(occupancy)
}

impl Carver<'_> {
    /// Decides the block of `size` voxels from `lo` (clipped to the grid) given the views
    /// of its parent, writing kept voxels into `out`, the slab starting at plane `i0`.
    fn decide(&self, lo: [usize; 3], size: usize, parent: &[View], i0: usize, out: &mut [bool]) {
        let hi: [usize; 3] = std::array::from_fn(|a| (lo[a] + size).min(self.grid.shape[a]));
        if (0..3).any(|a| lo[a] >= hi[a]) {
            return;
        }
        let views: Vec<View> = parent
            .iter()
            .enumerate()
            .map(|(c, &v)| {
                if v == View::Unsure {
                    self.view_of_box(c, lo, hi)
                } else {
                    v
                }
            })
            .collect();
        let rejections = views.iter().filter(|&&v| v == View::Empty).count();
        if rejections > self.tolerance {
            return;
        }
        let undecided = views.contains(&View::Unsure);
        if !undecided || (size == 1 && self.footprint == Footprint::Conservative) {
            self.keep(lo, hi, i0, out);
            return;
        }
        if size == 1 {
            let centre = self.centre(lo);
            let centre_rejections = views
                .iter()
                .enumerate()
                .filter(|&(c, &v)| v == View::Unsure && self.background_at(c, &centre))
                .count();
            if rejections + centre_rejections <= self.tolerance {
                self.keep(lo, hi, i0, out);
            }
            return;
        }
        let half = size / 2;
        for di in [0, half] {
            for dj in [0, half] {
                for dk in [0, half] {
                    self.decide([lo[0] + di, lo[1] + dj, lo[2] + dk], half, &views, i0, out);
                }
            }
        }
    }

    fn centre(&self, voxel: [usize; 3]) -> [f64; 3] {
        std::array::from_fn(|a| self.grid.origin[a] + self.grid.spacing * voxel[a] as f64)
    }

    fn keep(&self, lo: [usize; 3], hi: [usize; 3], i0: usize, out: &mut [bool]) {
        let [_, ny, nz] = self.grid.shape;
        for i in lo[0]..hi[0] {
            for j in lo[1]..hi[1] {
                let row = ((i - i0) * ny + j) * nz;
                out[row + lo[2]..row + hi[2]].fill(true);
            }
        }
    }

    /// The view of camera `c` on the box of voxels `lo..hi` (voxel faces, not centres).
    fn view_of_box(&self, c: usize, lo: [usize; 3], hi: [usize; 3]) -> View {
        let (cam, sil) = (&self.cameras[c], &self.silhouettes[c]);
        let h = self.grid.spacing;
        let corner = |a: usize, up: bool| {
            self.grid.origin[a] + h * (if up { hi[a] as f64 } else { lo[a] as f64 } - 0.5)
        };
        let (mut umin, mut vmin, mut umax, mut vmax) = (
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        );
        for n in 0..8 {
            let p = [
                corner(0, n & 1 != 0),
                corner(1, n & 2 != 0),
                corner(2, n & 4 != 0),
            ];
            let Some([u, v]) = cam.project(&p) else {
                return View::Unsure;
            };
            umin = umin.min(u);
            umax = umax.max(u);
            vmin = vmin.min(v);
            vmax = vmax.max(v);
        }
        // Pixel x covers [x - 0.5, x + 0.5); one pixel more on each side for distortion.
        let (x0, x1) = ((umin + 0.5).floor() - 1.0, (umax + 0.5).floor() + 1.0);
        let (y0, y1) = ((vmin + 0.5).floor() - 1.0, (vmax + 0.5).floor() + 1.0);
        let (w, hgt) = (sil.width as f64, sil.height as f64);
        if x1 < 0.0 || y1 < 0.0 || x0 > w - 1.0 || y0 > hgt - 1.0 {
            return View::Outside;
        }
        let inside_image = x0 >= 0.0 && y0 >= 0.0 && x1 <= w - 1.0 && y1 <= hgt - 1.0;
        let clip = |v: f64, max: f64| v.clamp(0.0, max) as usize;
        let (cx0, cx1, cy0, cy1) = (
            clip(x0, w - 1.0),
            clip(x1, w - 1.0),
            clip(y0, hgt - 1.0),
            clip(y1, hgt - 1.0),
        );
        let count = sil.count(cx0, cy0, cx1, cy1);
        let area = ((cx1 - cx0 + 1) * (cy1 - cy0 + 1)) as u32;
        match (count, inside_image) {
            (0, true) => View::Empty,
            (c, _) if c == area => View::Full,
            _ => View::Unsure,
        }
    }

    /// True when the pixel under `p` is background in camera `c` (false when unseen).
    fn background_at(&self, c: usize, p: &[f64; 3]) -> bool {
        let (cam, sil) = (&self.cameras[c], &self.silhouettes[c]);
        let Some([u, v]) = cam.project(p) else {
            return false;
        };
        let (x, y) = ((u + 0.5).floor(), (v + 0.5).floor());
        if !(x >= 0.0 && y >= 0.0 && x < sil.width as f64 && y < sil.height as f64) {
            return false;
        }
        sil.count(x as usize, y as usize, x as usize, y as usize) == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A camera at distance `d` on axis `axis` looking at the origin, f = 200 px.
    fn looking_at_origin(axis: usize, d: f64) -> Camera {
        // Rows of R are the camera axes in world coordinates; z looks at the origin.
        let r = match axis {
            0 => [0.0, 1.0, 0.0, 0.0, 0.0, 1.0, -1.0, 0.0, 0.0],
            1 => [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, -1.0, 0.0],
            _ => [1.0, 0.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, -1.0],
        };
        Camera::new(
            [200.0, 0.0, 99.5, 0.0, 200.0, 99.5, 0.0, 0.0, 1.0],
            [0.0; 5],
            r,
            [0.0, 0.0, d],
            200,
            200,
        )
        .unwrap()
    }

    fn disc_mask(cam: &Camera, radius: f64) -> Vec<u8> {
        // The silhouette of a sphere of `radius` at the origin seen from distance d.
        let mut mask = vec![0u8; cam.width * cam.height];
        for y in 0..cam.height {
            for x in 0..cam.width {
                let (dx, dy) = (x as f64 - 99.5, y as f64 - 99.5);
                // Angular radius of the sphere: sin(alpha) = r / d, d = 3.
                let alpha = (radius / 3.0f64).asin();
                if (dx * dx + dy * dy).sqrt() <= 200.0 * alpha.tan() {
                    mask[y * cam.width + x] = 255;
                }
            }
        }
        mask
    }

    #[test]
    fn sphere_hull_contains_the_sphere_and_is_bounded() {
        let cams: Vec<Camera> = (0..3).map(|a| looking_at_origin(a, 3.0)).collect();
        let sils: Vec<Silhouette> = cams
            .iter()
            .map(|c| Silhouette::new(&disc_mask(c, 0.5), 200, 200))
            .collect();
        let n = 40;
        let grid = GridSpec {
            origin: [-0.975; 3],
            spacing: 0.05,
            shape: [n; 3],
        };
        let occ = carve(&cams, &sils, grid, 0, Footprint::Conservative).unwrap();
        let centre = |i: usize| -0.975 + 0.05 * i as f64;
        let mut kept = 0;
        for i in 0..n {
            for j in 0..n {
                for k in 0..n {
                    let r = (centre(i).powi(2) + centre(j).powi(2) + centre(k).powi(2)).sqrt();
                    let o = occ[(i * n + j) * n + k];
                    if r < 0.5 {
                        assert!(o, "inside voxel carved at {i} {j} {k}");
                    }
                    // Seen by all three cameras (|coordinate| <= 0.75) and outside the
                    // hull of three discs (the sphere's cube-like hull reaches r = 0.5 sqrt 3).
                    let seen = [i, j, k].iter().all(|&v| centre(v).abs() <= 0.75);
                    if seen && r > 0.5 * 3f64.sqrt() + 0.1 {
                        assert!(!o, "far voxel kept at {i} {j} {k}");
                    }
                    kept += o as usize;
                }
            }
        }
        assert!(kept > 0);
        // Tolerance 3: every camera may disagree, nothing is carved.
        let all = carve(&cams, &sils, grid, 3, Footprint::Center).unwrap();
        assert!(all.iter().all(|&o| o));
    }

    #[test]
    fn carving_from_masks_equals_carving_from_silhouettes_and_checks_their_size() {
        let cams: Vec<Camera> = (0..3).map(|a| looking_at_origin(a, 3.0)).collect();
        let pixels: Vec<Vec<u8>> = cams.iter().map(|c| disc_mask(c, 0.4)).collect();
        let sils: Vec<Silhouette> = pixels
            .iter()
            .map(|m| Silhouette::new(m, 200, 200))
            .collect();
        let masks: Vec<Mask> = pixels
            .iter()
            .map(|m| Mask {
                pixels: m,
                width: 200,
                height: 200,
            })
            .collect();
        let grid = GridSpec {
            origin: [-0.7; 3],
            spacing: 0.05,
            shape: [29; 3],
        };
        let direct = carve(&cams, &sils, grid, 0, Footprint::Conservative).unwrap();
        let from_masks = carve_masks(&cams, &masks, grid, 0, Footprint::Conservative).unwrap();
        assert_eq!(direct, from_masks);
        assert!(direct.iter().any(|&o| o) && !direct.iter().all(|&o| o));
        let short = Mask {
            pixels: &pixels[0][..100],
            width: 200,
            height: 200,
        };
        assert!(matches!(
            carve_masks(&cams[..1], &[short], grid, 0, Footprint::Center),
            Err(Error::WrongLength { got: 100, .. })
        ));
    }
}
