//! Correlation of a template patch with search patches at arbitrary candidate centres
//! (seeding along an epipolar line: ~0.7 CPU s of a seeding frame of the 1024x768
//! capture, a third of it).
//!
//! A candidate's score is the dot product of the mean-free, unit-norm template and search
//! patches, each sum taken in `f64` in pixel order. Those sums are chains of dependent
//! additions: one candidate at a time, the score waited on the adder's latency at every
//! pixel. Four candidates are scored together, pixel by pixel, so four independent chains
//! fill the adder; each chain adds the same terms in the same order as one candidate alone
//! (and starts, as Rust's float `sum` does, from -0.0), so every score is the same to the
//! bit. The search windows go to one buffer per call, not one allocation per candidate.

use super::ncc::{fill_window, normalised, sample_window, window_inside};
use crate::lsm::ImageView;

/// Candidates scored together.
const GROUP: usize = 4;

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
    let n = size * size;
    let mut values = Vec::with_capacity(n);
    let template = if sample_window(template_image, point, size, &mut values) {
        normalised(&values)
    } else {
        None
    };
    let Some(template) = template else {
        scores
            .iter_mut()
            .zip(candidates)
            .for_each(|(s, _)| *s = f64::NAN);
        return;
    };
    // The windows of up to four candidates inside the image, and where their scores go.
    let mut windows = vec![0.0f32; GROUP * n];
    let mut pending = [0usize; GROUP];
    let mut count = 0;
    let count_scored = scores.len().min(candidates.len());
    for (k, &candidate) in candidates[..count_scored].iter().enumerate() {
        if !window_inside(search, candidate, size) {
            scores[k] = f64::NAN;
            continue;
        }
        fill_window(
            search,
            candidate,
            size,
            &mut windows[count * n..(count + 1) * n],
        );
        pending[count] = k;
        count += 1;
        if count == GROUP {
            let group = score_group(&template, &windows, n);
            for (&k, score) in pending.iter().zip(group) {
                scores[k] = score;
            }
            count = 0;
        }
    }
    if count > 0 {
        // The group's unused lanes repeat its first window (scored and dropped).
        let (first, rest) = windows.split_at_mut(n);
        for lane in rest.chunks_exact_mut(n).skip(count - 1) {
            lane.copy_from_slice(first);
        }
        let group = score_group(&template, &windows, n);
        for (&k, score) in pending[..count].iter().zip(group) {
            scores[k] = score;
        }
    }
}

/// The scores of the four windows `windows[j * n..(j + 1) * n]` against the normalised
/// `template`, each computed as `normalised` and the dot product compute one alone: the
/// mean, the norm of the mean-free window (NaN when flat), then the sum of the template
/// times the window's normalised values (rounded to `f32` as `normalised` stores them).
#[inline]
fn score_group(template: &[f32], windows: &[f32], n: usize) -> [f64; GROUP] {
    let lanes: [&[f32]; GROUP] = std::array::from_fn(|j| &windows[j * n..(j + 1) * n]);
    let count = n as f64;
    let mut sum = [-0.0f64; GROUP];
    for i in 0..n {
        for j in 0..GROUP {
            sum[j] += lanes[j][i] as f64;
        }
    }
    let mean = sum.map(|s| s / count);
    let mut square = [-0.0f64; GROUP];
    for i in 0..n {
        for j in 0..GROUP {
            square[j] += (lanes[j][i] as f64 - mean[j]).powi(2);
        }
    }
    let norm = square.map(f64::sqrt);
    let mut dot = [-0.0f64; GROUP];
    for (i, &t) in template.iter().enumerate() {
        for j in 0..GROUP {
            let s = ((lanes[j][i] as f64 - mean[j]) / norm[j]) as f32;
            dot[j] += (t * s) as f64;
        }
    }
    std::array::from_fn(|j| if norm[j] > 1e-9 { dot[j] } else { f64::NAN })
}
