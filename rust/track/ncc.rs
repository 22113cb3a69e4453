//! Normalised cross-correlation of a template patch over an integer box around a
//! prediction (the tracker's search); at arbitrary candidate centres (seeding along an
//! epipolar line) in `ncc_at`.
//!
//! The box search resamples one window of side `size + 2 radius` around the prediction
//! (bilinear, at the prediction's sub-pixel offset) and slides the template over it by
//! whole pixels, with the window's sums and sums of squares from summed-area tables: one
//! dot product of `size^2` per shift. The peak is refined to sub-pixel by a parabola
//! through it and its four neighbours.

use crate::lsm::ImageView;

/// Bilinear samples of a square window of side `side` centred on `centre` into `out`
/// (row-major); false when the window is not inside the image.
pub(crate) fn sample_window(
    image: &ImageView<'_>,
    centre: [f64; 2],
    side: usize,
    out: &mut Vec<f32>,
) -> bool {
    if !window_inside(image, centre, side) {
        return false;
    }
    out.clear();
    out.resize(side * side, 0.0);
    fill_window(image, centre, side, out);
    true
}

/// Whether the window of side `side` centred on `centre` lies inside the image (with the
/// last sample's right and lower neighbour).
pub(crate) fn window_inside(image: &ImageView<'_>, centre: [f64; 2], side: usize) -> bool {
    let half = (side / 2) as f64;
    let (u0, v0) = (centre[0] - half, centre[1] - half);
    let (w, h) = (image.width as f64, image.height as f64);
    // Written so that NaN fails; the last sample needs its right/lower neighbour.
    u0 >= 0.0 && v0 >= 0.0 && u0 + side as f64 <= w - 1.0 && v0 + side as f64 <= h - 1.0
}

/// The bilinear samples of the window (checked by [`window_inside`]) into `out`
/// (`side * side`, row-major).
pub(crate) fn fill_window(image: &ImageView<'_>, centre: [f64; 2], side: usize, out: &mut [f32]) {
    let half = (side / 2) as f64;
    let (u0, v0) = (centre[0] - half, centre[1] - half);
    let (iu, iv) = (u0.floor(), v0.floor());
    let (tu, tv) = ((u0 - iu) as f32, (v0 - iv) as f32);
    let (iu, iv) = (iu as usize, iv as usize);
    let width = image.width;
    // Rows written through slices (not pushed one sample at a time: the capacity check
    // of every push kept the loop scalar).
    for (r, dest) in out.chunks_exact_mut(side).enumerate() {
        let row0 = &image.data[(iv + r) * width + iu..(iv + r) * width + iu + side + 1];
        let row1 = &image.data[(iv + r + 1) * width + iu..(iv + r + 1) * width + iu + side + 1];
        for (c, value) in dest.iter_mut().enumerate() {
            let top = row0[c] + tu * (row0[c + 1] - row0[c]);
            let bottom = row1[c] + tu * (row1[c + 1] - row1[c]);
            *value = top + tv * (bottom - top);
        }
    }
}

/// Mean-free template with unit norm; `None` for a flat patch.
pub(crate) fn normalised(values: &[f32]) -> Option<Vec<f32>> {
    let mut out = Vec::with_capacity(values.len());
    normalised_into(values, &mut out).then_some(out)
}

/// [`normalised`] into `out` (a buffer kept by the caller: the box search ran one
/// allocation per view); false, `out` unspecified, for a flat patch.
pub(crate) fn normalised_into(values: &[f32], out: &mut Vec<f32>) -> bool {
    let n = values.len() as f64;
    let mean = values.iter().map(|&x| x as f64).sum::<f64>() / n;
    let norm = values
        .iter()
        .map(|&x| (x as f64 - mean).powi(2))
        .sum::<f64>()
        .sqrt();
    out.clear();
    // Written so that NaN is flat too.
    if norm > 1e-9 {
        out.extend(values.iter().map(|&x| ((x as f64 - mean) / norm) as f32));
        true
    } else {
        false
    }
}

/// Rows of the summed-area tables' first pass run side by side (independent running
/// sums, see [`summed_area_tables`]).
const SAT_ROWS: usize = 4;

/// Summed-area tables of the window (`side x side`, row-major) and of its squares into
/// `sum` and `square`, `(side + 1)^2` each with a zero first row and column:
/// `sum[(r + 1)(side + 1) + c + 1]` is the sum of the window's rows `0..=r`, columns
/// `0..=c`, in `f64`.
///
/// Each entry is the entry above plus the row's running sum up to it, the running sums
/// added column by column: the order of every sum is fixed, so that it is exact to compute
/// it in two passes: the running sums along the rows, [`SAT_ROWS`] rows side by side (one
/// row's sums are a serial chain of adds, and one row at a time waited on its latency),
/// then the rows of the table down the columns, a whole row of the table at once (vectors).
/// The entries are those of the single pass to the bit (`a + b == b + a` in IEEE
/// arithmetic; a running sum that starts at `+0` is never `-0`, so the zero first row
/// adds nothing).
pub(crate) fn summed_area_tables(
    window: &[f32],
    side: usize,
    sum: &mut Vec<f64>,
    square: &mut Vec<f64>,
) {
    let stride = side + 1;
    sum.clear();
    sum.resize(stride * stride, 0.0);
    square.clear();
    square.resize(stride * stride, 0.0);
    let mut r = 0;
    while r + SAT_ROWS <= side {
        let (mut row, mut row2) = ([0.0f64; SAT_ROWS], [0.0f64; SAT_ROWS]);
        for c in 0..side {
            for k in 0..SAT_ROWS {
                let x = window[(r + k) * side + c] as f64;
                row[k] += x;
                row2[k] += x * x;
                sum[(r + k + 1) * stride + c + 1] = row[k];
                square[(r + k + 1) * stride + c + 1] = row2[k];
            }
        }
        r += SAT_ROWS;
    }
    for r in r..side {
        let (mut row, mut row2) = (0.0f64, 0.0f64);
        for c in 0..side {
            let x = window[r * side + c] as f64;
            row += x;
            row2 += x * x;
            sum[(r + 1) * stride + c + 1] = row;
            square[(r + 1) * stride + c + 1] = row2;
        }
    }
    // Down the columns: table row `r + 1` += table row `r` (row 1 is the first running
    // sums already: the zero row adds nothing).
    for table in [sum, square] {
        for r in 1..side {
            let (above, below) = table.split_at_mut((r + 1) * stride);
            let above = &above[r * stride..];
            // `above + below`, the single pass's order (the same bits as `+=` but for
            // which NaN's payload a sum of two NaNs keeps).
            #[allow(clippy::assign_op_pattern)]
            for (b, &a) in below[..stride].iter_mut().zip(above) {
                *b = a + *b;
            }
        }
    }
}

/// The summed-area tables of [`summed_area_tables`] in one pass, one row after the other
/// (what the box search ran before; the tests' reference).
#[cfg(test)]
pub(crate) fn summed_area_tables_single_pass(window: &[f32], side: usize) -> (Vec<f64>, Vec<f64>) {
    let stride = side + 1;
    let (mut sum, mut square) = (vec![0.0; stride * stride], vec![0.0; stride * stride]);
    for r in 0..side {
        let (mut row, mut row2) = (0.0, 0.0);
        for c in 0..side {
            let x = window[r * side + c] as f64;
            row += x;
            row2 += x * x;
            sum[(r + 1) * stride + c + 1] = sum[r * stride + c + 1] + row;
            square[(r + 1) * stride + c + 1] = square[r * stride + c + 1] + row2;
        }
    }
    (sum, square)
}

/// The best shift of a box search.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NccBest {
    /// Sub-pixel centre of the best match, pixels.
    pub centre: [f64; 2],
    /// Its correlation (at the integer peak), -1..1.
    pub score: f64,
}

/// Shifts per row of the box search's fast paths: two registers of eight (radius up to 7,
/// the tracker's step) or three (radius up to 11, the coarse-to-fine first step's 8).
const MOST_LANES: usize = 24;

/// Per-worker scratch of the box search.
#[derive(Debug, Default)]
pub(crate) struct BoxScratch {
    pub(super) template: Vec<f32>,
    /// The template mean-free and of unit norm ([`normalised_into`]).
    normalised: Vec<f32>,
    window: Vec<f32>,
    padded: Vec<f32>,
    sum: Vec<f64>,
    square: Vec<f64>,
    pub(crate) scores: Vec<f64>,
    dots: Vec<f32>,
    /// The template's weights and the weighted search's buffers
    /// ([`super::weighted_ncc`]).
    pub(super) weighted: super::weighted_ncc::WeightedScratch,
}

/// Searches the template patch (side `size`, around `point` in `template_image`) in
/// `search` over integer shifts up to `radius` around `prediction`. `None` when a patch
/// or the window leaves its image, or the template is flat.
///
/// `weights`, when given, is an image of the template image's size whose values (0 to 1,
/// read bilinearly at the template's pixels, NaN as 0) weigh the template's pixels: the
/// correlation is then the weighted one ([`super::weighted_ncc`]), so pixels of weight 0
/// (the surface behind a limb's edge, cut by the caller) play no part in finding the
/// start. A template whose weights are all 1 is searched exactly as without weights.
pub(crate) fn box_search(
    template_image: &ImageView<'_>,
    point: [f64; 2],
    search: &ImageView<'_>,
    prediction: [f64; 2],
    size: usize,
    radius: usize,
    weights: Option<&ImageView<'_>>,
    scratch: &mut BoxScratch,
) -> Option<NccBest> {
    if !sample_window(template_image, point, size, &mut scratch.template) {
        return None;
    }
    if let Some(weights) = weights {
        if !super::weighted_ncc::all_ones(weights, point, size, &mut scratch.weighted) {
            return super::weighted_ncc::weighted_box_search(
                search, prediction, size, radius, scratch,
            );
        }
    }
    box_search_sampled(search, prediction, size, radius, scratch)
}

/// The box search of one point (see [`box_search`]), with the scores of every shift,
/// `(2 radius + 1)^2` row-major (rows: shifts down, columns: shifts right; `None` as in
/// [`box_search`]). For tests, benches and the binding; the tracker calls the search per
/// point with a scratch per worker.
#[allow(clippy::too_many_arguments)]
pub fn box_search_scores(
    template_image: &ImageView<'_>,
    point: [f64; 2],
    search: &ImageView<'_>,
    prediction: [f64; 2],
    size: usize,
    radius: usize,
    weights: Option<&ImageView<'_>>,
) -> Option<(NccBest, Vec<f64>)> {
    let mut scratch = BoxScratch::default();
    let best = box_search(
        template_image,
        point,
        search,
        prediction,
        size,
        radius,
        weights,
        &mut scratch,
    )?;
    Some((best, scratch.scores))
}

/// [`box_search`] of the template already sampled into `scratch.template`, unweighted.
pub(super) fn box_search_sampled(
    search: &ImageView<'_>,
    prediction: [f64; 2],
    size: usize,
    radius: usize,
    scratch: &mut BoxScratch,
) -> Option<NccBest> {
    if !normalised_into(&scratch.template, &mut scratch.normalised) {
        return None;
    }
    let side = size + 2 * radius;
    if !sample_window(search, prediction, side, &mut scratch.window) {
        return None;
    }
    summed_area_tables(&scratch.window, side, &mut scratch.sum, &mut scratch.square);
    let shifts = 2 * radius + 1;
    shift_dots(
        &scratch.window,
        side,
        &scratch.normalised,
        size,
        &mut scratch.padded,
        &mut scratch.dots,
    );
    plain_scores(
        &scratch.sum,
        &scratch.square,
        &scratch.dots,
        side,
        size,
        &mut scratch.scores,
    );
    // The first best in row-major order, as the scores were pushed before.
    let (mut best, mut best_at) = (f64::NEG_INFINITY, (radius, radius));
    for (i, &score) in scratch.scores.iter().enumerate() {
        if score > best {
            best = score;
            best_at = (i / shifts, i % shifts);
        }
    }
    Some(refine(&scratch.scores, best_at, best, prediction, radius))
}

/// The plain correlation of every shift (`(side + 1 - size)^2`, row-major, into `scores`)
/// from the window's summed-area tables ([`summed_area_tables`]) and the mean-free, unit
/// template's dot products `dots` ([`shift_dots`]). A row of shifts is one loop without
/// a branch (the choice of 0 for a flat window is a select), so that the square roots and
/// divisions run four to a vector instead of one by one (correctly rounded either way:
/// the same bits); the best shift is found after, in a loop of its own.
pub(crate) fn plain_scores(
    sum: &[f64],
    square: &[f64],
    dots: &[f32],
    side: usize,
    size: usize,
    scores: &mut Vec<f64>,
) {
    let (stride, shifts) = (side + 1, side + 1 - size);
    let n = (size * size) as f64;
    scores.clear();
    scores.resize(shifts * shifts, 0.0);
    for r in 0..shifts {
        // The box of shift (r, c): table rows r and r + size, columns c and c + size.
        let top = &sum[r * stride..r * stride + stride];
        let bottom = &sum[(r + size) * stride..(r + size) * stride + stride];
        let top2 = &square[r * stride..r * stride + stride];
        let bottom2 = &square[(r + size) * stride..(r + size) * stride + stride];
        let dots = &dots[r * shifts..(r + 1) * shifts];
        let out = &mut scores[r * shifts..(r + 1) * shifts];
        for c in 0..shifts {
            let s = bottom[c + size] - top[c + size] - bottom[c] + top[c];
            let ss = bottom2[c + size] - top2[c + size] - bottom2[c] + top2[c];
            let variance = ss - s * s / n;
            // The template is mean-free, so the window's mean drops out of the dot product.
            let score = dots[c] as f64 / variance.sqrt();
            out[c] = if variance > 1e-9 { score } else { 0.0 };
        }
    }
}

/// The dot products of `template` (`size x size`) with the window (`side x side`,
/// `side = size + 2 radius`) at each of the `(2 radius + 1)^2` shifts, row-major into
/// `out`: the plain search's and the weighted search's ([`super::weighted_ncc`]) one kernel.
///
/// A row of shifts at once: each template sample times a run of `shifts` window samples, a
/// loop the compiler vectorises (the per-shift dot product of `size^2` terms is a serial
/// sum it cannot). Up to 16 shifts a row (radius 7), or 24 (radius 11), the window is
/// copied into rows of stride `size + 16` (or `+ 24`; zero beyond the window) so that the
/// inner loop runs over two (three) whole vector registers; the run of `shifts` (13 at the
/// default radius, 17 at the coarse-to-fine first step's radius 8) otherwise leaves a
/// remainder loop and its set-up at every one of the `size^2` template samples (profiled:
/// a third of the tracker's step went there at radius 6 before the 16 lanes; at radius 8,
/// which had no fixed-width path, a quarter of the first step's calls, themselves a
/// quarter of the step). The sums run in the same order on every path, so the dot
/// products are the same to the bit.
pub(super) fn shift_dots(
    window: &[f32],
    side: usize,
    template: &[f32],
    size: usize,
    padded: &mut Vec<f32>,
    out: &mut Vec<f32>,
) {
    let shifts = side + 1 - size;
    out.clear();
    out.resize(shifts * shifts, 0.0);
    if shifts <= 16 {
        padded_rows::<2>(window, side, template, size, padded, out);
    } else if shifts <= MOST_LANES {
        padded_rows::<3>(window, side, template, size, padded, out);
    } else {
        general_rows(window, side, template, size, out);
    }
}

/// [`shift_dots`] with `R` registers of eight shifts a row (`shifts <= 8 R`).
fn padded_rows<const R: usize>(
    window: &[f32],
    side: usize,
    template: &[f32],
    size: usize,
    padded: &mut Vec<f32>,
    out: &mut [f32],
) {
    let shifts = side + 1 - size;
    let stride = size + 8 * R;
    padded.clear();
    padded.resize(side * stride, 0.0);
    for r in 0..side {
        padded[r * stride..r * stride + side].copy_from_slice(&window[r * side..(r + 1) * side]);
    }
    for r in 0..shifts {
        let acc = row_of_shifts::<R>(&padded[r * stride..(r + size) * stride], template, size);
        out[r * shifts..(r + 1) * shifts].copy_from_slice(&acc[..shifts]);
    }
}

/// [`shift_dots`] of any number of shifts a row: a run of `shifts` window samples per
/// template sample (the reference the fixed-width rows are tested against).
pub(super) fn general_rows(
    window: &[f32],
    side: usize,
    template: &[f32],
    size: usize,
    out: &mut [f32],
) {
    let shifts = side + 1 - size;
    for r in 0..shifts {
        let dots = &mut out[r * shifts..(r + 1) * shifts];
        for tr in 0..size {
            let row = &window[(r + tr) * side..(r + tr + 1) * side];
            for (j, &t) in template[tr * size..(tr + 1) * size].iter().enumerate() {
                for (dot, &w) in dots.iter_mut().zip(&row[j..j + shifts]) {
                    *dot += w * t;
                }
            }
        }
    }
}

/// The best shift `best_at` (row, column) of the `(2 radius + 1)^2` `scores` (row-major)
/// refined to sub-pixel by a parabola through it and its four neighbours.
pub(super) fn refine(
    scores: &[f64],
    best_at: (usize, usize),
    best: f64,
    prediction: [f64; 2],
    radius: usize,
) -> NccBest {
    let shifts = 2 * radius + 1;
    let (r, c) = best_at;
    let at = |r: usize, c: usize| scores[r * shifts + c];
    let vertex = |minus: f64, centre: f64, plus: f64| {
        let curvature = minus - 2.0 * centre + plus;
        if curvature < 0.0 {
            (0.5 * (minus - plus) / curvature).clamp(-0.5, 0.5)
        } else {
            0.0
        }
    };
    let du = if c > 0 && c + 1 < shifts {
        vertex(at(r, c - 1), best, at(r, c + 1))
    } else {
        0.0
    };
    let dv = if r > 0 && r + 1 < shifts {
        vertex(at(r - 1, c), best, at(r + 1, c))
    } else {
        0.0
    };
    NccBest {
        centre: [
            prediction[0] + (c as f64 - radius as f64) + du,
            prediction[1] + (r as f64 - radius as f64) + dv,
        ],
        score: best,
    }
}

/// The dot products of the template (`size x size`, mean-free) with the `8 R` windows
/// starting at the first `8 R` columns of `rows` (`size` rows of stride `size + 8 R`), in
/// the first `8 R` entries.
fn row_of_shifts<const R: usize>(rows: &[f32], template: &[f32], size: usize) -> [f32; MOST_LANES] {
    #[cfg(target_arch = "x86_64")]
    if crate::lsm::wide() {
        // SAFETY: `wide` checked that the CPU has AVX2 and FMA.
        return unsafe { row_of_shifts_wide::<R>(rows, template, size) };
    }
    let stride = size + 8 * R;
    let mut acc = [[0.0f32; 8]; R];
    for tr in 0..size {
        let row = &rows[tr * stride..(tr + 1) * stride];
        for (j, &t) in template[tr * size..(tr + 1) * size].iter().enumerate() {
            for (q, lanes) in acc.iter_mut().enumerate() {
                let run: &[f32; 8] = row[j + 8 * q..j + 8 * q + 8]
                    .try_into()
                    .expect("padded row");
                for (a, &w) in lanes.iter_mut().zip(run) {
                    *a += w * t;
                }
            }
        }
    }
    let mut out = [0.0f32; MOST_LANES];
    for (q, lanes) in acc.iter().enumerate() {
        out[8 * q..8 * q + 8].copy_from_slice(lanes);
    }
    out
}

/// [`row_of_shifts`] in `R` AVX registers of eight lanes (the portable build's SSE2 takes
/// four, and the compiler, left to itself under AVX2, shuffled a sixteen-lane array
/// between half registers: slower than SSE2). A multiply then an add, as the portable
/// loop (no fused multiply-add), so the dot products are the same to the bit.
///
/// # Safety
/// The CPU must have AVX2 and FMA ([`crate::lsm::wide`]).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn row_of_shifts_wide<const R: usize>(
    rows: &[f32],
    template: &[f32],
    size: usize,
) -> [f32; MOST_LANES] {
    use std::arch::x86_64::{
        _mm256_add_ps, _mm256_loadu_ps, _mm256_mul_ps, _mm256_set1_ps, _mm256_setzero_ps,
        _mm256_storeu_ps,
    };
    let stride = size + 8 * R;
    let mut acc = [_mm256_setzero_ps(); R];
    for tr in 0..size {
        let row = &rows[tr * stride..(tr + 1) * stride];
        for (j, &t) in template[tr * size..(tr + 1) * size].iter().enumerate() {
            let run = &row[j..j + 8 * R];
            let t = _mm256_set1_ps(t);
            for (q, a) in acc.iter_mut().enumerate() {
                // SAFETY: `run` holds `8 R` floats: an unaligned load of eight at `8 q`.
                let w = unsafe { _mm256_loadu_ps(run.as_ptr().add(8 * q)) };
                *a = _mm256_add_ps(*a, _mm256_mul_ps(w, t));
            }
        }
    }
    let mut out = [0.0f32; MOST_LANES];
    for (q, a) in acc.iter().enumerate() {
        // SAFETY: `out` holds 24 floats, `8 q + 8 <= 24`.
        unsafe { _mm256_storeu_ps(out.as_mut_ptr().add(8 * q), *a) };
    }
    out
}

#[cfg(test)]
#[path = "ncc_tests.rs"]
mod tests;
