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

use super::ncc::window_inside;
use super::ncc_at::{fill_lane, score_group, template_patch, GROUP};
use super::ncc_at_estimate::{estimate, fill_rows};
use crate::lsm::ImageView;

/// Bound on the difference between a trusted estimate and the exact score (the analysis
/// above gives below 3e-7).
const SLACK: f64 = 1e-5;
/// The threshold is lowered by this much more, so that the caller's `peak - rival >=
/// uniqueness` (rounded) holds for every replaced rival.
const MARGIN: f64 = 1e-6;

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
