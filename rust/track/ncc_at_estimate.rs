//! The cheap correlation estimate of [`super::ncc_at_decisive`] and the bilinear fill it
//! shares with [`super::ncc_at`]'s exact path.
//!
//! A window's estimate is `(sum t w - mean sum t) / sqrt(sum w^2 - mean sum w)` from three
//! sums taken in any order (error bound: [`super::ncc_at_decisive`]'s module text). The
//! window's samples are [`fill_window`]'s, sample for sample; they are made eight columns at
//! a time ([`bilinear_blocks`]) into a stored window that [`estimate`] reads back. (Summing
//! the samples as each block is made, without the store, was slower: 207-214 ns a position
//! on big16's seeding frame 5 against 128-131; benches/README.md, "seedmain1".)

use super::ncc::fill_window;
use super::ncc_at::window_corner;
use crate::lsm::ImageView;

/// Columns filled together: one `f32` register of AVX2.
pub(super) const BLOCK: usize = 8;

/// An estimate is trusted where the window's summed squared deviation exceeds this part
/// of its summed squares (a standard deviation above 1e-3 of the root mean square).
const CONTRAST: f64 = 1e-6;

/// [`fill_window`]'s samples (the same arithmetic, sample for sample) of a window of side
/// `side` (at least [`BLOCK`]), handed to `emit(row, column, samples)` eight columns at a
/// time, block by block: a window side of 15 is the block at column 0 and the one at
/// column 7 (the overlapping column comes twice with the same values).
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
    for block in 0..side.div_ceil(BLOCK) {
        let start = (block * BLOCK).min(side - BLOCK);
        let mut top = across(0, start);
        for r in 0..side {
            let bottom = across(r + 1, start);
            let samples: [f32; BLOCK] = std::array::from_fn(|j| top[j] + tv * (bottom[j] - top[j]));
            emit(r, start, &samples);
            top = bottom;
        }
    }
}

/// [`fill_window`]'s samples (the same arithmetic, sample for sample) into `out`
/// (row-major), by [`bilinear_blocks`]; sides below [`BLOCK`] go through [`fill_window`].
#[inline(always)]
pub(super) fn fill_rows(image: &ImageView<'_>, centre: [f64; 2], side: usize, out: &mut [f32]) {
    if side < BLOCK {
        fill_window(image, centre, side, out);
        return;
    }
    bilinear_blocks(image, centre, side, |r, start, samples| {
        out[r * side + start..][..BLOCK].copy_from_slice(samples);
    });
}

/// `x * y + s`, fused where the caller is compiled for FMA (`FUSED`). Used only where `x`
/// and `y` are `f32` values: their product is exact in `f64`, so both forms round once, to
/// the same value.
#[inline(always)]
fn madd<const FUSED: bool>(x: f64, y: f64, s: f64) -> f64 {
    if FUSED {
        x.mul_add(y, s)
    } else {
        x * y + s
    }
}

/// The estimate from the window's sum, sum of squares and dot product with the template
/// (each summed in lanes), over `n` samples; `None` where the window's variance is too
/// small a part of its second moment for the estimate to be within the caller's slack of
/// the exact score (or not finite).
#[inline(always)]
fn finish(sum: &[f64], square: &[f64], dot: &[f64], n: usize, template_sum: f64) -> Option<f64> {
    let (sum, square, dot) = (
        sum.iter().sum::<f64>(),
        square.iter().sum::<f64>(),
        dot.iter().sum::<f64>(),
    );
    let mean = sum / n as f64;
    let variance = square - sum * mean;
    // Written so that NaN is not trusted; the second test keeps the norm far above the
    // exact score's flat threshold (1e-9).
    if !(variance > CONTRAST * square && variance > 1e-12) {
        return None;
    }
    let score = (dot - mean * template_sum) / variance.sqrt();
    score.is_finite().then_some(score)
}

/// The correlation estimate of the contiguous `window` (row-major, as `template`) with the
/// normalised `template` (its `f32` values in `f64`, summing to `template_sum`): see
/// [`finish`]. With `FUSED` the squares and products are added by fused multiply-adds
/// (the AVX2 build), which gives the same estimate to the bit ([`madd`]; tested).
#[inline(always)]
pub(super) fn estimate<const FUSED: bool>(
    template: &[f64],
    template_sum: f64,
    window: &[f32],
) -> Option<f64> {
    const LANES: usize = 8;
    let mut sum = [0.0f64; LANES];
    let mut square = [0.0f64; LANES];
    let mut dot = [0.0f64; LANES];
    let (w_main, w_rest) = window.split_at(window.len() / LANES * LANES);
    let (t_main, t_rest) = template.split_at(w_main.len());
    for (w, t) in w_main.chunks_exact(LANES).zip(t_main.chunks_exact(LANES)) {
        for j in 0..LANES {
            let x = w[j] as f64;
            sum[j] += x;
            square[j] = madd::<FUSED>(x, x, square[j]);
            dot[j] = madd::<FUSED>(t[j], x, dot[j]);
        }
    }
    for (&w, &t) in w_rest.iter().zip(t_rest) {
        let x = w as f64;
        sum[0] += x;
        square[0] = madd::<FUSED>(x, x, square[0]);
        dot[0] = madd::<FUSED>(t, x, dot[0]);
    }
    finish(&sum, &square, &dot, window.len(), template_sum)
}
