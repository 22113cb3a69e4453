//! Correlation of a template patch with search patches at arbitrary candidate centres
//! (seeding along an epipolar line: ~0.4 CPU s of a seeding frame of the 1024x768
//! capture, nearly half of `seed_points`; benches/README.md, "seedfast1", "seedcost1").
//!
//! A candidate's score is the dot product of the mean-free, unit-norm template and search
//! patches, each sum taken in `f64` in pixel order. Those sums are chains of dependent
//! additions: one candidate at a time, the score waited on the adder's latency at every
//! pixel. Eight candidates are scored together, pixel by pixel, so eight independent chains
//! fill the adder; each chain adds the same terms in the same order as one candidate alone
//! (and starts, as Rust's float `sum` does, from -0.0), so every score is the same to the
//! bit. The search windows go to one buffer per call, pixel-major (the eight candidates'
//! samples of a pixel side by side, one vector load), not one allocation per candidate.
//!
//! The normalised window value `((x - mean) / norm) as f32` was one `f64` division per
//! pixel. It is computed as `(x - mean) * (1 / norm)` instead, which
//! differs from the quotient by a few units in the last place of the `f64`, then rounded to
//! `f32`: the same `f32` unless the product lies within a few `f64` units of a rounding
//! midpoint between two `f32`s (see [`near_f32_tie`]). A group where any value does (about
//! one value in 17 million) is scored again with the division, so every score is still
//! the division's to the bit. On CPUs with AVX2 the same code is compiled for it (four
//! `f64` lanes a register instead of SSE2's two; no fused multiply-add is formed, so the
//! arithmetic is unchanged).

use super::ncc::{normalised, sample_window, window_inside};
use super::ncc_at_estimate::{bilinear_blocks, BLOCK};
use crate::lsm::ImageView;

/// Candidates scored together.
pub(super) const GROUP: usize = 8;

/// Correlation of the template patch around `point` with the patch of `search` around
/// each of `candidates` (bilinear at sub-pixel centres); NaN where a patch leaves its image
/// or is flat. Writes `scores[k]` for `candidates[k]`.
pub fn ncc_at(
    template_image: &ImageView<'_>,
    point: [f64; 2],
    search: &ImageView<'_>,
    candidates: &[[f64; 2]],
    size: usize,
    scores: &mut [f64],
) {
    #[cfg(target_arch = "x86_64")]
    if crate::lsm::wide() {
        // SAFETY: `wide` checked that the CPU has AVX2 and FMA.
        unsafe { ncc_at_wide(template_image, point, search, candidates, size, scores) };
        return;
    }
    ncc_at_body(template_image, point, search, candidates, size, scores);
}

/// [`ncc_at`] compiled for AVX2 (the same operations in wider registers).
///
/// # Safety
/// The CPU must have AVX2 and FMA ([`crate::lsm::wide`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn ncc_at_wide(
    template_image: &ImageView<'_>,
    point: [f64; 2],
    search: &ImageView<'_>,
    candidates: &[[f64; 2]],
    size: usize,
    scores: &mut [f64],
) {
    ncc_at_body(template_image, point, search, candidates, size, scores);
}

#[inline(always)]
fn ncc_at_body(
    template_image: &ImageView<'_>,
    point: [f64; 2],
    search: &ImageView<'_>,
    candidates: &[[f64; 2]],
    size: usize,
    scores: &mut [f64],
) {
    let n = size * size;
    let mut values = Vec::with_capacity(n);
    let template = template_patch(template_image, point, size, &mut values);
    let Some(template) = template else {
        scores
            .iter_mut()
            .zip(candidates)
            .for_each(|(s, _)| *s = f64::NAN);
        return;
    };
    // The windows of up to eight candidates inside the image, pixel-major, and where their
    // scores go.
    let mut windows = vec![0.0f32; GROUP * n];
    let mut pending = [0usize; GROUP];
    let mut count = 0;
    let count_scored = scores.len().min(candidates.len());
    for (k, &candidate) in candidates[..count_scored].iter().enumerate() {
        if !window_inside(search, candidate, size) {
            scores[k] = f64::NAN;
            continue;
        }
        fill_lane(search, candidate, size, &mut windows, count);
        pending[count] = k;
        count += 1;
        if count == GROUP {
            let group = score_group(&template, &windows);
            for (&k, score) in pending.iter().zip(group) {
                scores[k] = score;
            }
            count = 0;
        }
    }
    if count > 0 {
        // The group's unused lanes repeat its first window (scored and dropped).
        for pixel in windows.chunks_exact_mut(GROUP) {
            let first = pixel[0];
            pixel[count..].fill(first);
        }
        let group = score_group(&template, &windows);
        for (&k, score) in pending[..count].iter().zip(group) {
            scores[k] = score;
        }
    }
}

/// The normalised template patch of side `size` around `point` ([`normalised`]); `None`
/// where it leaves its image or is flat. `values` is scratch (left holding the samples).
#[inline(always)]
pub(super) fn template_patch(
    image: &ImageView<'_>,
    point: [f64; 2],
    size: usize,
    values: &mut Vec<f32>,
) -> Option<Vec<f32>> {
    if sample_window(image, point, size, values) {
        normalised(values)
    } else {
        None
    }
}

/// The integer pixel at the top left of the window of side `side` centred on `centre`
/// (a window [`window_inside`] accepts) and the bilinear fractions along a row and down a
/// column, as [`super::ncc::fill_window`] computes them.
#[inline(always)]
pub(super) fn window_corner(centre: [f64; 2], side: usize) -> (usize, usize, f32, f32) {
    let half = (side / 2) as f64;
    let (u0, v0) = (centre[0] - half, centre[1] - half);
    let (iu, iv) = (u0.floor(), v0.floor());
    (iu as usize, iv as usize, (u0 - iu) as f32, (v0 - iv) as f32)
}

/// The bilinear samples of the window of side `side` centred on `centre` (checked by
/// [`window_inside`]) into lane `lane` of the pixel-major `windows`: pixel `i` at
/// `windows[i * GROUP + lane]`. [`super::ncc::fill_window`]'s arithmetic, sample for
/// sample (written in place: filling a window then copying it across cost ~5% more);
/// sides of eight and more by [`bilinear_blocks`] (each interpolation along a row once).
#[inline(always)]
pub(super) fn fill_lane(
    image: &ImageView<'_>,
    centre: [f64; 2],
    side: usize,
    windows: &mut [f32],
    lane: usize,
) {
    if side >= BLOCK {
        bilinear_blocks(image, centre, side, |r, start, block| {
            let first = (r * side + start) * GROUP + lane;
            for (j, &value) in block.iter().enumerate() {
                windows[first + j * GROUP] = value;
            }
        });
        return;
    }
    let (iu, iv, tu, tv) = window_corner(centre, side);
    let width = image.width;
    for (r, dest) in windows[..side * side * GROUP]
        .chunks_exact_mut(side * GROUP)
        .enumerate()
    {
        let row0 = &image.data[(iv + r) * width + iu..][..side + 1];
        let row1 = &image.data[(iv + r + 1) * width + iu..][..side + 1];
        for (c, pixel) in dest.chunks_exact_mut(GROUP).enumerate() {
            let top = row0[c] + tu * (row0[c + 1] - row0[c]);
            let bottom = row1[c] + tu * (row1[c + 1] - row1[c]);
            pixel[lane] = top + tv * (bottom - top);
        }
    }
}

/// The scores of the eight windows (pixel-major: pixel `i` of window `j` at
/// `windows[i * GROUP + j]`) against the normalised `template`, each computed as
/// `normalised` and the dot product compute one alone: the mean, the norm of the
/// mean-free window (NaN when flat), then the sum of the template times the window's
/// normalised values (rounded to `f32` as `normalised` stores them).
#[inline(always)]
pub(super) fn score_group(template: &[f32], windows: &[f32]) -> [f64; GROUP] {
    let (mean, norm) = moments(windows, template.len());
    let inverse = norm.map(|x| 1.0 / x);
    let mut dot = [-0.0f64; GROUP];
    let mut ties = 0u64;
    for (&t, pixel) in template.iter().zip(windows.chunks_exact(GROUP)) {
        for j in 0..GROUP {
            let product = (pixel[j] as f64 - mean[j]) * inverse[j];
            ties |= near_f32_tie(product) as u64;
            dot[j] += (t * product as f32) as f64;
        }
    }
    if ties != 0 {
        dot = dots_divided(template, windows, mean, norm);
    }
    std::array::from_fn(|j| if norm[j] > 1e-9 { dot[j] } else { f64::NAN })
}

/// The eight windows' means and norms of the mean-free values ([`normalised`]'s sums, in
/// its order).
#[inline(always)]
fn moments(windows: &[f32], n: usize) -> ([f64; GROUP], [f64; GROUP]) {
    let count = n as f64;
    let mut sum = [-0.0f64; GROUP];
    for pixel in windows.chunks_exact(GROUP) {
        for j in 0..GROUP {
            sum[j] += pixel[j] as f64;
        }
    }
    let mean = sum.map(|s| s / count);
    let mut square = [-0.0f64; GROUP];
    for pixel in windows.chunks_exact(GROUP) {
        for j in 0..GROUP {
            square[j] += (pixel[j] as f64 - mean[j]).powi(2);
        }
    }
    (mean, square.map(f64::sqrt))
}

/// The dot products with the windows' values divided by their norms, as [`normalised`]
/// computes them (the rare group where a product by the inverse may round otherwise).
#[cold]
#[inline(never)]
fn dots_divided(
    template: &[f32],
    windows: &[f32],
    mean: [f64; GROUP],
    norm: [f64; GROUP],
) -> [f64; GROUP] {
    let mut dot = [-0.0f64; GROUP];
    for (&t, pixel) in template.iter().zip(windows.chunks_exact(GROUP)) {
        for j in 0..GROUP {
            let s = ((pixel[j] as f64 - mean[j]) / norm[j]) as f32;
            dot[j] += (t * s) as f64;
        }
    }
    dot
}

/// Whether rounding `x` (a product within a few units in the last place of an `f64`
/// quotient `q`) to `f32` may give another `f32` than rounding `q`: when `x` lies within
/// 16 `f64` units of a midpoint between two `f32`s, or in the `f32` subnormal range.
///
/// Rounding to `f32` is monotone, so `x` and `q` round apart only when a midpoint `m` lies
/// between them (or one of them is `m`). A midpoint keeps 25 significant bits: its
/// `f64` mantissa's low 29 bits are `1 << 28`, and it lies at least half an `f32` unit
/// (2^28 `f64` units) inside its binade, so `x` within 16 units of it is in the same
/// binade and its low 29 bits are within 16 of `1 << 28`. The product `(x - mean) *
/// (1 / norm)` is within 3 units of the quotient (two roundings against one; 6 of the
/// lower binade's where they straddle a power of two).
#[inline(always)]
pub(super) fn near_f32_tie(x: f64) -> bool {
    const LOW: u64 = (1 << 29) - 1;
    let bits = x.to_bits();
    let tie = (bits.wrapping_add(16) & LOW & !31) == 1 << 28;
    let tiny = x.abs() < f32::MIN_POSITIVE as f64 && x != 0.0;
    tie | tiny
}
