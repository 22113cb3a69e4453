//! The box search's correlation with per-pixel template weights.
//!
//! A point on a fast limb is lost on its first steps largely because its patch straddles
//! the limb's edge onto the surface behind it, which moves otherwise (benches/README.md,
//! track13). The caller can cut those pixels from the least-squares match with a weight
//! image (`elastocap.tracking.depth_weights`), but the box search, which finds the match's
//! start, correlated the whole patch: the straddling patch's peak sits between the two
//! motions, or under the box's threshold, and the weighted match never runs (track16).
//! Here the box search correlates with the same weights the match gets:
//!
//! $$\rho = \frac{\sum w (t - \bar t_w)(s - \bar s_w)}
//!              {\sqrt{\sum w (t - \bar t_w)^2 \; \sum w (s - \bar s_w)^2}}$$
//!
//! with $\bar x_w = \sum w x / \sum w$; for $w \equiv 1$ it is the plain correlation. Per
//! shift, three dot products over the patch (the template's weighted deviations with the
//! window, the weights with the window, the weights with the window's squares), each by the
//! plain search's kernel ([`super::ncc::shift_dots`]), where the plain search needs one (its
//! window sums come from summed-area tables, which weights defeat).

use super::ncc::{box_search_sampled, refine, sample_window, shift_dots, BoxScratch, NccBest};
use crate::lsm::ImageView;

/// Least total weight of a weighted template, as a share of its pixels: with less, the
/// few pixels left place no match (a quarter of the 15 px patch is a 7 px wide strip), and
/// the template is searched as without weights.
const MIN_WEIGHT_SHARE: f64 = 0.25;

/// The weighted search's buffers (in [`BoxScratch`], one per worker).
#[derive(Debug, Default)]
pub(crate) struct WeightedScratch {
    /// The template's weights, clamped to 0..1 (NaN as 0).
    weights: Vec<f32>,
    /// The weighted, mean-free template of unit weighted norm.
    template: Vec<f32>,
    /// The search window less its mean, and its squares.
    window: Vec<f32>,
    squares: Vec<f32>,
    padded: Vec<f32>,
    dots: Vec<f32>,
    sums: Vec<f32>,
    squared_sums: Vec<f32>,
}

/// Reads the weights of the template around `point` (side `size`; bilinear, as the
/// template's values) into `scratch`; true when every one is 1 (or the weight image does
/// not cover the patch): the template is then searched as without weights.
pub(super) fn all_ones(
    weights: &ImageView<'_>,
    point: [f64; 2],
    size: usize,
    scratch: &mut WeightedScratch,
) -> bool {
    if !sample_window(weights, point, size, &mut scratch.weights) {
        return true;
    }
    let mut all = true;
    for w in scratch.weights.iter_mut() {
        *w = if w.is_nan() { 0.0 } else { w.clamp(0.0, 1.0) };
        all &= *w >= 1.0;
    }
    all
}

/// The box search of the template in `scratch.template` with the weights
/// [`all_ones`] read into `scratch.weighted` (see [`super::ncc::box_search`]). `None`
/// when the window leaves the image or the weighted template is flat.
pub(super) fn weighted_box_search(
    search: &ImageView<'_>,
    prediction: [f64; 2],
    size: usize,
    radius: usize,
    scratch: &mut BoxScratch,
) -> Option<NccBest> {
    let ws = &mut scratch.weighted;
    let values = &scratch.template;
    let n = size * size;
    let total: f64 = ws.weights.iter().map(|&w| w as f64).sum();
    if total < MIN_WEIGHT_SHARE * n as f64 {
        return box_search_sampled(search, prediction, size, radius, scratch);
    }
    let mean = ws
        .weights
        .iter()
        .zip(values)
        .map(|(&w, &t)| w as f64 * t as f64)
        .sum::<f64>()
        / total;
    let norm = ws
        .weights
        .iter()
        .zip(values)
        .map(|(&w, &t)| w as f64 * (t as f64 - mean).powi(2))
        .sum::<f64>()
        .sqrt();
    if !(norm > 1e-9) {
        return None;
    }
    ws.template.clear();
    ws.template.extend(
        ws.weights
            .iter()
            .zip(values)
            .map(|(&w, &t)| (w as f64 * (t as f64 - mean) / norm) as f32),
    );
    let side = size + 2 * radius;
    if !sample_window(search, prediction, side, &mut ws.window) {
        return None;
    }
    // The window less its mean: the weighted variance is a difference of two sums, which
    // in single precision would lose the texture to the grey level's square otherwise.
    let centre = (ws.window.iter().map(|&x| x as f64).sum::<f64>() / (side * side) as f64) as f32;
    ws.squares.clear();
    for x in ws.window.iter_mut() {
        *x -= centre;
        ws.squares.push(*x * *x);
    }
    shift_dots(
        &ws.window,
        side,
        &ws.template,
        size,
        &mut ws.padded,
        &mut ws.dots,
    );
    shift_dots(
        &ws.window,
        side,
        &ws.weights,
        size,
        &mut ws.padded,
        &mut ws.sums,
    );
    shift_dots(
        &ws.squares,
        side,
        &ws.weights,
        size,
        &mut ws.padded,
        &mut ws.squared_sums,
    );
    let shifts = 2 * radius + 1;
    scratch.scores.clear();
    let (mut best, mut best_at) = (f64::NEG_INFINITY, (radius, radius));
    for i in 0..shifts * shifts {
        let s = ws.sums[i] as f64;
        let variance = ws.squared_sums[i] as f64 - s * s / total;
        // Sum w (t - mean_w) = 0, so the window's weighted mean drops out of the dot.
        let score = if variance > 1e-9 {
            ws.dots[i] as f64 / variance.sqrt()
        } else {
            0.0
        };
        scratch.scores.push(score);
        if score > best {
            best = score;
            best_at = (i / shifts, i % shifts);
        }
    }
    Some(refine(&scratch.scores, best_at, best, prediction, radius))
}
