//! The template patch: grey values and gradients, sampled once per point, and the sums
//! over it that every iteration reuses; single-precision dot products.
//!
//! Pixel `(u, v)` = (column, row), pixel centres at integers.

use super::dots::{dots, dots_into};
use super::resample::{bilinear, cubic_blend, cubic_cell, inside};
use super::types::{ImageView, Interpolation};

/// The template patch of one point: grey values and central-difference gradients on the
/// `size x size` grid of offsets `(dx, dy)`, `dx, dy in -h..=h`, plus the sums that make
/// the geometric part of the normal equations constant over the iterations.
#[derive(Debug, Clone)]
pub(crate) struct TemplatePatch {
    /// Side of the patch.
    pub size: usize,
    /// Offsets of each patch pixel from the centre, columns and rows (zero-padded to a
    /// multiple of eight).
    pub dx: Vec<f32>,
    /// See `dx`.
    pub dy: Vec<f32>,
    /// Offsets of the patch widened by one pixel on every side, `(size + 2)^2` row by
    /// row, padded like `dx` (the final state's search gradients are sampled on it).
    pub ring_dx: Vec<f32>,
    /// See `ring_dx`.
    pub ring_dy: Vec<f32>,
    /// Grey values.
    pub value: Vec<f32>,
    /// The six geometric Jacobian columns per pixel, `[gx, gy, gx dx, gx dy, gy dx, gy dy]`,
    /// stored column after column (`geo[k * n + i]`).
    pub geo: Vec<f32>,
    /// `sum g g^T` over the patch (6x6, row-major, f64).
    pub geo_normal: [f64; 36],
    /// `sum g`.
    pub geo_sum: [f64; 6],
    /// `sum g T`.
    pub geo_value: [f64; 6],
    /// `sum T`.
    pub value_sum: f64,
    /// `sum T^2`.
    pub value_square: f64,
    /// Square roots of the per-pixel weights when the patch is weighted (`weigh`), empty
    /// otherwise. A weighted patch stores `value` and `geo` multiplied by them, and every
    /// search patch is multiplied by them after resampling: the rows of the least-squares
    /// system are scaled by `sqrt(w)`, so every sum above is a weighted sum.
    pub root_weight: Vec<f32>,
    /// `sum w`: the number of pixels, or their total weight when weighted.
    pub weight_total: f64,
    /// Ones, one per pixel: the unweighted patch's root weights, so that a plain sum is
    /// the dot product with them in the fused sums (`super::dots`; the same bits as `sum`).
    unit: Vec<f32>,
    /// Grid of `(size + 2)^2` samples for the gradients (scratch).
    border: Vec<f32>,
    /// Bicubic cells and weights of the grid's columns, then rows (scratch).
    cells: Vec<(usize, [f32; 4])>,
    /// The columns' weights tap by tap (scratch).
    taps: Vec<f32>,
}

/// The upper triangle of the 6x6 `sum g g^T`, row by row.
#[rustfmt::skip]
const UPPER: [(usize, usize); 21] = [
    (0, 0), (0, 1), (0, 2), (0, 3), (0, 4), (0, 5),
    (1, 1), (1, 2), (1, 3), (1, 4), (1, 5),
    (2, 2), (2, 3), (2, 4), (2, 5),
    (3, 3), (3, 4), (3, 5),
    (4, 4), (4, 5),
    (5, 5),
];

impl Default for TemplatePatch {
    fn default() -> Self {
        Self {
            size: 0,
            dx: Vec::new(),
            dy: Vec::new(),
            ring_dx: Vec::new(),
            ring_dy: Vec::new(),
            value: Vec::new(),
            geo: Vec::new(),
            geo_normal: [0.0; 36],
            geo_sum: [0.0; 6],
            geo_value: [0.0; 6],
            value_sum: 0.0,
            value_square: 0.0,
            root_weight: Vec::new(),
            weight_total: 0.0,
            unit: Vec::new(),
            border: Vec::new(),
            cells: Vec::new(),
            taps: Vec::new(),
        }
    }
}

impl TemplatePatch {
    /// Number of pixels.
    pub fn len(&self) -> usize {
        self.size * self.size
    }

    /// Samples the patch around `centre`; false when it (with the one-pixel border the
    /// gradients need) does not lie inside the image.
    pub fn sample(
        &mut self,
        image: &ImageView<'_>,
        centre: [f64; 2],
        size: usize,
        interpolation: Interpolation,
    ) -> bool {
        let h = (size / 2) as f64;
        let reach = h + 1.0;
        if !inside(image, centre, [[reach, 0.0], [0.0, reach]], interpolation) {
            return false;
        }
        if self.size != size {
            self.resize(size);
        }
        let n = size * size;
        let m = size + 2;
        let base = [centre[0].floor(), centre[1].floor()];
        let frac = [(centre[0] - base[0]) as f32, (centre[1] - base[1]) as f32];
        let reach = size / 2 + 1;
        if frac == [0.0, 0.0] {
            // A pixel centre: the samples are the pixels themselves.
            let (u0, v0) = (base[0] as usize - reach, base[1] as usize - reach);
            for r in 0..m {
                let row = (v0 + r) * image.width + u0;
                self.border[r * m..(r + 1) * m].copy_from_slice(&image.data[row..row + m]);
            }
        } else if matches!(interpolation, Interpolation::Bilinear)
            && base[0] >= reach as f64
            && base[1] >= reach as f64
            && (base[0] as usize) + reach + 1 < image.width
            && (base[1] as usize) + reach + 1 < image.height
        {
            // The patch is not warped: every sample has the same sub-pixel weights, so
            // rows of pixels are blended with them directly (the per-sample path finds
            // the cell and the weights again for each of the (size + 2)^2 samples, which
            // profiled at a sixth of the tracker's step).
            let (tu, tv) = (frac[0], frac[1]);
            let (u0, v0) = (base[0] as usize - reach, base[1] as usize - reach);
            let width = image.width;
            for r in 0..m {
                let top = &image.data[(v0 + r) * width + u0..(v0 + r) * width + u0 + m + 1];
                let bottom =
                    &image.data[(v0 + r + 1) * width + u0..(v0 + r + 1) * width + u0 + m + 1];
                for c in 0..m {
                    let t = top[c] + tu * (top[c + 1] - top[c]);
                    let b = bottom[c] + tu * (bottom[c + 1] - bottom[c]);
                    self.border[r * m + c] = t + tv * (b - t);
                }
            }
        } else if matches!(interpolation, Interpolation::Bicubic) {
            self.bicubic_grid(image, base, frac, reach);
        } else {
            for r in 0..m {
                for c in 0..m {
                    let offset = [
                        frac[0] + (c as f32 - reach as f32),
                        frac[1] + (r as f32 - reach as f32),
                    ];
                    self.border[r * m + c] = bilinear(image, base, offset);
                }
            }
        }
        self.values_and_gradients();
        // The two sums alone, after the loop above: serial `f64` chains (their order is
        // their value), which inside it kept the values' and gradients' loop scalar.
        let (mut sum_value, mut sum_square) = (0.0f64, 0.0f64);
        for &t in &self.value {
            sum_value += t as f64;
            sum_square += (t as f64) * (t as f64);
        }
        self.value_sum = sum_value;
        self.value_square = sum_square;
        self.root_weight.clear();
        self.weight_total = n as f64;
        self.geo_sums();
        true
    }

    /// The grey values (`value`) and the six geometric Jacobian columns (`geo`) from the
    /// widened grid of samples (`border`, `(size + 2)^2`): central differences, row by
    /// row, each row's columns one vector loop (no sum in it, so it vectorises).
    fn values_and_gradients(&mut self) {
        let (size, m) = (self.size, self.size + 2);
        let n = size * size;
        let (value, geo, border) = (&mut self.value, &mut self.geo, &self.border);
        let (gx_col, rest) = geo.split_at_mut(n);
        let (gy_col, rest) = rest.split_at_mut(n);
        let (gxdx_col, rest) = rest.split_at_mut(n);
        let (gxdy_col, rest) = rest.split_at_mut(n);
        let (gydx_col, gydy_col) = rest.split_at_mut(n);
        for r in 0..size {
            let (above, centre, below) = (
                &border[r * m..(r + 1) * m],
                &border[(r + 1) * m..(r + 2) * m],
                &border[(r + 2) * m..(r + 3) * m],
            );
            let span = r * size..(r + 1) * size;
            let (dx, dy) = (&self.dx[span.clone()], &self.dy[span.clone()]);
            let value = &mut value[span.clone()];
            let gx_col = &mut gx_col[span.clone()];
            let gy_col = &mut gy_col[span.clone()];
            let gxdx_col = &mut gxdx_col[span.clone()];
            let gxdy_col = &mut gxdy_col[span.clone()];
            let gydx_col = &mut gydx_col[span.clone()];
            let gydy_col = &mut gydy_col[span];
            // Every operand a slice of exactly `size` (the compiler then drops the bounds
            // checks, which kept the loop scalar).
            let (left, middle, right) =
                (&centre[..size], &centre[1..size + 1], &centre[2..size + 2]);
            let (above, below) = (&above[1..size + 1], &below[1..size + 1]);
            for c in 0..size {
                let gx = 0.5 * (right[c] - left[c]);
                let gy = 0.5 * (below[c] - above[c]);
                value[c] = middle[c];
                gx_col[c] = gx;
                gy_col[c] = gy;
                gxdx_col[c] = gx * dx[c];
                gxdy_col[c] = gx * dy[c];
                gydx_col[c] = gy * dx[c];
                gydy_col[c] = gy * dy[c];
            }
        }
    }

    /// The widened grid's bicubic samples (`size + 2` squared, into `border`) around
    /// `base + frac`, each as `super::resample::bicubic` computes it at the offset
    /// `frac + (c - reach, r - reach)`. That offset's cell and weights depend on the column
    /// alone across and on the row alone down, so they are computed once per column and
    /// per row (the per-sample path recomputed them for each of the samples: a sixth of
    /// the spatial matches' time, perf on a tracked frame); where the columns' cells are
    /// consecutive (always, but for rounding at a cell's edge) a row of samples blends
    /// contiguous pixels, which vectorises. Same arithmetic per sample, same bits.
    fn bicubic_grid(
        &mut self,
        image: &ImageView<'_>,
        base: [f64; 2],
        frac: [f32; 2],
        reach: usize,
    ) {
        let m = self.size + 2;
        // Scratch kept across points (no allocation per point): columns' cells, then rows'.
        let mut cells = std::mem::take(&mut self.cells);
        cells.clear();
        for (frac, base, size) in [
            (frac[0], base[0], image.width),
            (frac[1], base[1], image.height),
        ] {
            cells.extend((0..m).map(|k| cubic_cell(base, frac + (k as f32 - reach as f32), size)));
        }
        let (columns, rows) = cells.split_at(m);
        let first = columns[0].0;
        if columns
            .iter()
            .enumerate()
            .any(|(c, &(iu, _))| iu != first + c)
        {
            for (r, &(iv, wv)) in rows.iter().enumerate() {
                for (c, &(iu, wu)) in columns.iter().enumerate() {
                    self.border[r * m + c] = cubic_blend(image, iu, iv, wu, wv);
                }
            }
            self.cells = cells;
            return;
        }
        // The weights tap by tap, so that the blend of a row reads them as vectors.
        let mut taps = std::mem::take(&mut self.taps);
        taps.clear();
        for j in 0..4 {
            taps.extend(columns.iter().map(|(_, w)| w[j]));
        }
        let (w0, rest) = taps.split_at(m);
        let (w1, rest) = rest.split_at(m);
        let (w2, w3) = rest.split_at(m);
        let width = image.width;
        for (r, &(iv, wv)) in rows.iter().enumerate() {
            let out = &mut self.border[r * m..(r + 1) * m];
            out.fill(0.0);
            for (k, &w) in wv.iter().enumerate() {
                let at = (iv + k - 1) * width + first - 1;
                let p = &image.data[at..at + m + 3];
                for c in 0..m {
                    out[c] +=
                        w * (w0[c] * p[c] + w1[c] * p[c + 1] + w2[c] * p[c + 2] + w3[c] * p[c + 3]);
                }
            }
        }
        self.cells = cells;
        self.taps = taps;
    }

    /// The sums over `geo` (and, when weighted, the value sums again).
    fn geo_sums(&mut self) {
        let n = self.len();
        let weighted = !self.root_weight.is_empty();
        if weighted {
            let [value_sum, value_square] =
                dots([(&self.root_weight, &self.value), (&self.value, &self.value)]);
            self.value_sum = value_sum;
            self.value_square = value_square;
        }
        // The 33 sums in groups of eight side by side (`dots_into`: the same bits as one
        // `dot` after the other): `sum w g_k` (`sum g_k` unweighted: the unit weights),
        // `sum g_k T`, then the upper triangle of `sum g_k g_l`.
        let g = |k: usize| &self.geo[k * n..(k + 1) * n];
        let weights = self.weights();
        let pairs: [(&[f32], &[f32]); 33] = std::array::from_fn(|i| match i {
            0..6 => (weights, g(i)),
            6..12 => (g(i - 6), self.value.as_slice()),
            _ => {
                let (k, l) = UPPER[i - 12];
                (g(k), g(l))
            }
        });
        let mut out = [0.0; 33];
        dots_into(&pairs, &mut out);
        self.geo_sum.copy_from_slice(&out[..6]);
        self.geo_value.copy_from_slice(&out[6..12]);
        for (&(k, l), &s) in UPPER.iter().zip(&out[12..]) {
            self.geo_normal[k * 6 + l] = s;
            self.geo_normal[l * 6 + k] = s;
        }
    }

    /// The root weights of a weighted patch, the unit weights otherwise (`n` values).
    pub fn weights(&self) -> &[f32] {
        if self.weighted() {
            &self.root_weight
        } else {
            &self.unit
        }
    }

    /// Weighs the sampled patch by `weights` (an image of the template's size, values
    /// clamped to `[0, 1]`, read bilinearly at the patch's pixels around `centre`, the
    /// point `sample` was given): weighted least squares, $\sum_x w(x) e(x)^2$. A
    /// template pixel of weight 0 (a silhouette mask's background) then plays no part in
    /// the match, its correlation or its texture measure; a pixel weighs at most what its
    /// four neighbours do (its gradient reads them). A patch whose weights are all 1
    /// stays unweighted (the same arithmetic as without weights). Returns the total
    /// weight.
    pub fn weigh(&mut self, weights: &ImageView<'_>, centre: [f64; 2]) -> f64 {
        let (n, size, m) = (self.len(), self.size, self.size + 2);
        let base = [centre[0].floor(), centre[1].floor()];
        // Inside the silhouette (most points) every weight the patch reads is 1: a scan of
        // the pixels its bilinear samples can touch decides that without resampling.
        let reach = (size / 2 + 2) as f64;
        let clamp = |x: f64, last: usize| x.clamp(0.0, last as f64) as usize;
        let (u0, u1) = (
            clamp(base[0] - reach, weights.width - 1),
            clamp(base[0] + reach, weights.width - 1),
        );
        let (v0, v1) = (
            clamp(base[1] - reach, weights.height - 1),
            clamp(base[1] + reach, weights.height - 1),
        );
        // A fold without early exit over each row: it vectorises (an `all` stops at the
        // first miss and stays scalar); NaN weights fail the test either way.
        if (v0..=v1).all(|v| {
            weights.data[v * weights.width + u0..=v * weights.width + u1]
                .iter()
                .fold(true, |all, &w| all & (w >= 1.0))
        }) {
            return self.weight_total;
        }
        let frac = [(centre[0] - base[0]) as f32, (centre[1] - base[1]) as f32];
        let h = (size / 2) as f32 + 1.0;
        // The gradient border's samples are spent: its buffer holds the weights on the
        // widened grid, and the root weights reuse their own buffer (no allocation per point).
        let mut grid = std::mem::take(&mut self.border);
        for (i, g) in grid.iter_mut().enumerate() {
            let offset = [frac[0] + (i % m) as f32 - h, frac[1] + (i / m) as f32 - h];
            let w = bilinear(weights, base, offset);
            *g = if w.is_nan() { 0.0 } else { w.clamp(0.0, 1.0) };
        }
        let mut root = std::mem::take(&mut self.root_weight);
        root.clear();
        root.resize(n, 0.0);
        let mut total = 0.0f64;
        let mut all = true;
        for (i, r) in root.iter_mut().enumerate() {
            // A pixel's central-difference gradient reads its four neighbours: next to a
            // pixel of low weight (the background) it mixes the two, so it weighs no more
            // than they do (a one-pixel erosion of the weights).
            let at = |rr: usize, cc: usize| grid[rr * m + cc];
            let (rr, cc) = (i / size + 1, i % size + 1);
            let w = at(rr, cc)
                .min(at(rr - 1, cc))
                .min(at(rr + 1, cc))
                .min(at(rr, cc - 1))
                .min(at(rr, cc + 1));
            all &= w >= 1.0;
            total += w as f64;
            *r = w.sqrt();
        }
        self.border = grid;
        if all {
            root.clear();
            self.root_weight = root;
            return self.weight_total;
        }
        for (t, &r) in self.value.iter_mut().zip(&root) {
            *t *= r;
        }
        for k in 0..6 {
            for (g, &r) in self.geo[k * n..(k + 1) * n].iter_mut().zip(&root) {
                *g *= r;
            }
        }
        self.root_weight = root;
        self.weight_total = total;
        self.geo_sums();
        total
    }

    /// Whether the patch is weighted.
    pub fn weighted(&self) -> bool {
        !self.root_weight.is_empty()
    }

    /// Scales a resampled search patch by the root weights (nothing when unweighted).
    pub fn weigh_samples(&self, samples: &mut [f32]) {
        for (s, &r) in samples.iter_mut().zip(&self.root_weight) {
            *s *= r;
        }
    }

    /// Root mean square gradient along the patch's weakest direction: the square root of
    /// the smaller eigenvalue of the mean structure tensor `mean(grad T grad T^T)`.
    pub fn weakest_gradient(&self) -> f64 {
        let n = self.weight_total;
        let (a, b, c) = (
            self.geo_normal[0] / n,
            self.geo_normal[1] / n,
            self.geo_normal[7] / n,
        );
        let mean = 0.5 * (a + c);
        let spread = (0.25 * (a - c) * (a - c) + b * b).sqrt();
        (mean - spread).max(0.0).sqrt()
    }

    fn resize(&mut self, size: usize) {
        let n = size * size;
        let h = (size / 2) as f32;
        self.size = size;
        // Padded with zero offsets to whole groups of eight, so that the resampling
        // computes positions eight lanes at a time without a remainder loop.
        let padded = n.div_ceil(8) * 8;
        let offset = |i: usize, along: fn(usize, usize) -> usize| {
            if i < n {
                along(i, size) as f32 - h
            } else {
                0.0
            }
        };
        self.dx = (0..padded).map(|i| offset(i, |i, s| i % s)).collect();
        self.dy = (0..padded).map(|i| offset(i, |i, s| i / s)).collect();
        let m = size + 2;
        let ring = (m * m).div_ceil(8) * 8;
        let ring_offset = |i: usize, along: fn(usize, usize) -> usize| {
            if i < m * m {
                along(i, m) as f32 - h - 1.0
            } else {
                0.0
            }
        };
        self.ring_dx = (0..ring).map(|i| ring_offset(i, |i, s| i % s)).collect();
        self.ring_dy = (0..ring).map(|i| ring_offset(i, |i, s| i / s)).collect();
        self.value = vec![0.0; n];
        self.unit = vec![1.0; n];
        self.geo = vec![0.0; 6 * n];
        self.border = vec![0.0; (size + 2) * (size + 2)];
    }
}

#[cfg(test)]
#[path = "sample_tests.rs"]
mod tests;

/// `sum a_i b_i` in eight `f32` lanes (so that it vectorises), then `f64`: over a patch
/// of at most 255^2 pixels, about 1e-6 relative.
#[inline]
pub(crate) fn dot(a: &[f32], b: &[f32]) -> f64 {
    let mut lanes = [0.0f32; 8];
    let (ca, ra) = a.as_chunks::<8>();
    let (cb, rb) = b.as_chunks::<8>();
    for (x, y) in ca.iter().zip(cb) {
        for l in 0..8 {
            lanes[l] += x[l] * y[l];
        }
    }
    let tail: f64 = ra.iter().zip(rb).map(|(&x, &y)| x as f64 * y as f64).sum();
    lanes.iter().map(|&l| l as f64).sum::<f64>() + tail
}

/// `sum a_i` in eight `f32` lanes, then `f64`: what the plain sums were before they
/// became dot products with the unit weights (`super::dots`); the tests' reference.
#[cfg(test)]
pub(crate) fn sum(a: &[f32]) -> f64 {
    let mut lanes = [0.0f32; 8];
    let (chunks, rest) = a.as_chunks::<8>();
    for x in chunks {
        for l in 0..8 {
            lanes[l] += x[l];
        }
    }
    lanes.iter().map(|&l| l as f64).sum::<f64>() + rest.iter().map(|&x| x as f64).sum::<f64>()
}
