//! Seeding's correlation along a line with only the scores that can decide its test
//! computed exactly (~55% of `seed_points`' CPU went to [`super::ncc_at`]; benches/README.md,
//! "seedcost1", "seedfloor1").
//!
//! Seeding (`python/elastocap/tracking/seeding.py`) keeps a candidate's best depth sample
//! when its score (the peak `P`) reaches `min_correlation` and beats every local maximum
//! more than `_PEAK_WIDTH` samples away by `uniqueness`; the match starts there. A score
//! below `max(min_correlation, P) - uniqueness` cannot change that decision: it is not the
//! peak, a rival below `P - uniqueness` does not refuse it, and a neighbour at or above that
//! level stays a local maximum (`>=`) whatever lower value replaces it; in a row whose `P`
//! is below `min_correlation` nothing is kept whatever the scores below it. So those scores
//! need not be exact, and ~85% of the positions of a seeding frame are such.
//!
//! Every position gets a cheap estimate first: the sums of the window, of its squares and
//! of its product with the template, in any order (one vectorised pass over a contiguous
//! window) give `(sum t w - mean sum t) / sqrt(sum w^2 - mean sum w)`, the same correlation
//! up to rounding. Where the window's variance is not a small difference of large sums
//! (the estimate is trusted) its error against the exact score is below 3e-7 (the exact
//! score's own `f32` roundings, 2^-23 of a unit dot; the `f64` sums' ~3 n 2^-53 relative to
//! the window's second moment, divided by a standard deviation of at least 1e-3 of it), and
//! [`SLACK`] is 30 times that. Positions whose estimate plus [`SLACK`] stays below the row's
//! threshold (its best estimate minus [`SLACK`] stands for `P`) come back as -inf; the rest,
//! and every window whose estimate is not trusted, are scored by [`super::ncc_at`]'s own
//! grouped arithmetic, so they are its scores to the bit.

use super::ncc::{fill_window, window_inside};
use super::ncc_at::{fill_lane, score_group, template_patch, window_corner, GROUP};
use crate::lsm::ImageView;

/// Bound on the difference between a trusted estimate and the exact score (the analysis
/// above gives below 3e-7).
const SLACK: f64 = 1e-5;
/// The threshold is lowered by this much more, so that the caller's `peak - rival >=
/// uniqueness` (rounded) holds for every replaced rival.
const MARGIN: f64 = 1e-6;
/// An estimate is trusted where the window's summed squared deviation exceeds this part
/// of its summed squares (a standard deviation above 1e-3 of the root mean square).
const CONTRAST: f64 = 1e-6;

/// [`super::ncc_at`]'s scores where they can decide seeding's test, -inf where they cannot:
/// in a row (one template, `candidates` along its line) whose best score `P` is below
/// `min_correlation` any in-image score may be -inf; in any other row a score may be -inf
/// only if it is below `P - uniqueness`. Every other score (NaN outside the image or flat)
/// equals [`super::ncc_at`]'s to the bit.
#[allow(clippy::too_many_arguments)]
pub fn ncc_at_decisive(
    template_image: &ImageView<'_>,
    point: [f64; 2],
    search: &ImageView<'_>,
    candidates: &[[f64; 2]],
    size: usize,
    min_correlation: f64,
    uniqueness: f64,
    scores: &mut [f64],
) {
    #[cfg(target_arch = "x86_64")]
    if crate::lsm::wide() {
        // SAFETY: `wide` checked that the CPU has AVX2 and FMA.
        unsafe {
            decisive_wide(
                template_image,
                point,
                search,
                candidates,
                size,
                min_correlation,
                uniqueness,
                scores,
            )
        };
        return;
    }
    decisive_body::<false>(
        template_image,
        point,
        search,
        candidates,
        size,
        min_correlation,
        uniqueness,
        scores,
    );
}

/// [`ncc_at_decisive`] compiled for AVX2 (the estimate's sums four `f64` lanes a register,
/// its products added fused, which rounds as the separate product and sum do: see
/// [`estimate`]; the exact scores form no fused multiply-add, so their arithmetic is
/// unchanged).
///
/// # Safety
/// The CPU must have AVX2 and FMA ([`crate::lsm::wide`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
#[allow(clippy::too_many_arguments)]
unsafe fn decisive_wide(
    template_image: &ImageView<'_>,
    point: [f64; 2],
    search: &ImageView<'_>,
    candidates: &[[f64; 2]],
    size: usize,
    min_correlation: f64,
    uniqueness: f64,
    scores: &mut [f64],
) {
    decisive_body::<true>(
        template_image,
        point,
        search,
        candidates,
        size,
        min_correlation,
        uniqueness,
        scores,
    );
}

#[inline(always)]
#[allow(clippy::too_many_arguments)]
fn decisive_body<const FUSED: bool>(
    template_image: &ImageView<'_>,
    point: [f64; 2],
    search: &ImageView<'_>,
    candidates: &[[f64; 2]],
    size: usize,
    min_correlation: f64,
    uniqueness: f64,
    scores: &mut [f64],
) {
    let n = size * size;
    let mut values = Vec::with_capacity(n);
    let template = template_patch(template_image, point, size, &mut values);
    let count = scores.len().min(candidates.len());
    let Some(template) = template else {
        scores[..count].fill(f64::NAN);
        return;
    };
    let template_sum: f64 = template.iter().map(|&t| t as f64).sum();
    // In `f64` once for the row, not converted again for every position's estimate.
    let template_wide: Vec<f64> = template.iter().map(|&t| t as f64).collect();
    values.resize(n, 0.0);
    // The estimates (NaN outside the image and where not trusted) and the positions scored
    // exactly whatever the threshold (in the image, estimate not trusted).
    let mut estimates = vec![f64::NAN; count];
    let mut untrusted = Vec::new();
    let mut top = f64::NEG_INFINITY;
    for (k, &candidate) in candidates[..count].iter().enumerate() {
        if !window_inside(search, candidate, size) {
            scores[k] = f64::NAN;
            continue;
        }
        fill_rows(search, candidate, size, &mut values);
        match estimate::<FUSED>(&template_wide, template_sum, &values) {
            Some(e) => {
                estimates[k] = e;
                top = top.max(e);
            }
            None => untrusted.push(k),
        }
    }
    let mut windows = vec![0.0f32; GROUP * n];
    score_exactly(
        &template,
        search,
        candidates,
        size,
        &untrusted,
        &mut windows,
        scores,
    );
    let exact_best = untrusted
        .iter()
        .map(|&k| scores[k])
        .filter(|s| !s.is_nan())
        .fold(f64::NEG_INFINITY, f64::max);
    // A row whose best score cannot reach `min_correlation` keeps nothing.
    let threshold = if (top + SLACK).max(exact_best) < min_correlation {
        f64::INFINITY
    } else {
        min_correlation.max((top - SLACK).max(exact_best)) - uniqueness - MARGIN
    };
    let mut decisive = Vec::new();
    for (k, &e) in estimates.iter().enumerate() {
        if e.is_nan() {
            continue;
        }
        if e + SLACK >= threshold {
            decisive.push(k);
        } else {
            scores[k] = f64::NEG_INFINITY;
        }
    }
    score_exactly(
        &template,
        search,
        candidates,
        size,
        &decisive,
        &mut windows,
        scores,
    );
}

/// Columns filled together: one `f32` register of AVX2.
pub(super) const BLOCK: usize = 8;

/// [`fill_window`]'s samples (the same arithmetic, sample for sample) of a window of side
/// `side` (at least [`BLOCK`]), handed to `emit(row, column, block)` eight columns at a
/// time: a window side of 15 is the block at column 0 and the one at column 7 (the
/// overlapping column comes twice with the same values).
///
/// A column block is walked down the window's rows with the last interpolation along a
/// row kept: [`fill_window`]'s `bottom` of row `r` is its `top` of row `r + 1` (the same
/// operations on the same pixels, so the same `f32`), and computing it once takes a third
/// of the fill's arithmetic away (benches/README.md, "seedmain1").
#[inline(always)]
pub(super) fn bilinear_blocks(
    image: &ImageView<'_>,
    centre: [f64; 2],
    side: usize,
    mut emit: impl FnMut(usize, usize, &[f32; BLOCK]),
) {
    debug_assert!(side >= BLOCK);
    let (iu, iv, tu, tv) = window_corner(centre, side);
    let width = image.width;
    let across = |r: usize, start: usize| -> [f32; BLOCK] {
        let row: &[f32; BLOCK + 1] = image.data[(iv + r) * width + iu + start..][..BLOCK + 1]
            .try_into()
            .unwrap();
        std::array::from_fn(|j| row[j] + tu * (row[j + 1] - row[j]))
    };
    let mut c = 0;
    loop {
        let start = c.min(side - BLOCK);
        let mut top = across(0, start);
        for r in 0..side {
            let bottom = across(r + 1, start);
            let block: [f32; BLOCK] = std::array::from_fn(|j| top[j] + tv * (bottom[j] - top[j]));
            emit(r, start, &block);
            top = bottom;
        }
        if start + BLOCK == side {
            break;
        }
        c += BLOCK;
    }
}

/// [`fill_window`]'s samples (the same arithmetic, sample for sample) into `out`
/// (row-major), by [`bilinear_blocks`]; sides below [`BLOCK`] go through [`fill_window`].
/// With [`fill_window`]'s loop, which the compiler left one column at a time, the
/// estimates of big16's seeding frame 5 took 208 ns a position, with blocks of eight
/// columns 148 (benches/README.md, "seedfloor1").
#[inline(always)]
pub(super) fn fill_rows(image: &ImageView<'_>, centre: [f64; 2], side: usize, out: &mut [f32]) {
    if side < BLOCK {
        fill_window(image, centre, side, out);
        return;
    }
    bilinear_blocks(image, centre, side, |r, start, block| {
        out[r * side + start..][..BLOCK].copy_from_slice(block);
    });
}

/// The correlation of the contiguous `window` (row-major, as `template`) with the
/// normalised `template` (its `f32` values in `f64`, summing to `template_sum`) from three
/// sums taken in any order; `None` where the window's variance is too small a part of its
/// second moment for the estimate to be within [`SLACK`] of the exact score (or not
/// finite).
///
/// With `FUSED` the squares and products are added by fused multiply-adds (the AVX2 build):
/// a product of two `f32`s is exact in `f64`, so `x * y + s` rounds once either way and
/// both forms give the same estimate to the bit (tested).
#[inline(always)]
pub(super) fn estimate<const FUSED: bool>(
    template: &[f64],
    template_sum: f64,
    window: &[f32],
) -> Option<f64> {
    const LANES: usize = 8;
    let madd = |x: f64, y: f64, s: f64| if FUSED { x.mul_add(y, s) } else { x * y + s };
    let mut sum = [0.0f64; LANES];
    let mut square = [0.0f64; LANES];
    let mut dot = [0.0f64; LANES];
    let (w_main, w_rest) = window.split_at(window.len() / LANES * LANES);
    let (t_main, t_rest) = template.split_at(w_main.len());
    for (w, t) in w_main.chunks_exact(LANES).zip(t_main.chunks_exact(LANES)) {
        for j in 0..LANES {
            let x = w[j] as f64;
            sum[j] += x;
            square[j] = madd(x, x, square[j]);
            dot[j] = madd(t[j], x, dot[j]);
        }
    }
    for (&w, &t) in w_rest.iter().zip(t_rest) {
        let x = w as f64;
        sum[0] += x;
        square[0] = madd(x, x, square[0]);
        dot[0] = madd(t, x, dot[0]);
    }
    let (sum, square, dot) = (
        sum.iter().sum::<f64>(),
        square.iter().sum::<f64>(),
        dot.iter().sum::<f64>(),
    );
    let mean = sum / window.len() as f64;
    let variance = square - sum * mean;
    // Written so that NaN is not trusted; the second test keeps the norm far above the
    // exact score's flat threshold (1e-9).
    if !(variance > CONTRAST * square && variance > 1e-12) {
        return None;
    }
    let score = (dot - mean * template_sum) / variance.sqrt();
    score.is_finite().then_some(score)
}

/// [`super::ncc_at`]'s scores of `candidates[k]` for each `k` of `which` into `scores[k]`,
/// eight at a time with its arithmetic (a lane's score does not depend on the others').
fn score_exactly(
    template: &[f32],
    search: &ImageView<'_>,
    candidates: &[[f64; 2]],
    size: usize,
    which: &[usize],
    windows: &mut [f32],
    scores: &mut [f64],
) {
    for group in which.chunks(GROUP) {
        for (lane, &k) in group.iter().enumerate() {
            fill_lane(search, candidates[k], size, windows, lane);
        }
        if group.len() < GROUP {
            // Unused lanes repeat the first window (scored and dropped).
            for pixel in windows.chunks_exact_mut(GROUP) {
                let first = pixel[0];
                pixel[group.len()..].fill(first);
            }
        }
        let got = score_group(template, windows);
        for (&k, score) in group.iter().zip(got) {
            scores[k] = score;
        }
    }
}
