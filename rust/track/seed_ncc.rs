//! Normalised cross-correlation along a seed's line (the seeding's depth search): the same
//! scores as [`super::ncc_at`], bit for bit, computed several candidates at a time.
//!
//! A seeding frame scores ~1.4 M candidate centres (96 depth samples of each seed in one or
//! two partner cameras, benches/README.md "seedframe1"). Per candidate, `ncc_at`'s time is
//! three f64 sums of `size^2` terms in a fixed order (the mean, the sum of squares, the dot
//! product): each is one dependent chain of additions, so the core waits on the adder's
//! latency at every term. Here `LANES` candidates' chains run interleaved: every chain keeps
//! its own terms in its own order (the same operations, so the same rounding), and the
//! independent chains fill the adder's pipeline. The window's normalisation (a division per
//! pixel) runs per candidate as in `ncc_at`.

use super::ncc::{normalised, sample_window};
use crate::lsm::ImageView;

/// Candidates scored together: enough independent chains to cover an f64 addition's
/// latency (4 cycles at 2 per cycle).
const LANES: usize = 8;

/// Correlation of the template patch around `point` with the patch of `search` around
/// each of `candidates` (bilinear at sub-pixel centres); NaN where a patch leaves its image
/// or is flat. Writes `scores[k]` for `candidates[k]`: equal bit for bit to
/// [`super::ncc_at`]'s.
pub fn line_ncc(
    template_image: &ImageView<'_>,
    point: [f64; 2],
    search: &ImageView<'_>,
    candidates: &[[f64; 2]],
    size: usize,
    scores: &mut [f64],
) {
    let mut values = Vec::with_capacity(size * size);
    let template = if sample_window(template_image, point, size, &mut values) {
        normalised(&values)
    } else {
        None
    };
    let Some(template) = template else {
        scores.fill(f64::NAN);
        return;
    };
    let mut windows: [Vec<f32>; LANES] = std::array::from_fn(|_| vec![0.0; size * size]);
    let mut at = [0usize; LANES];
    let mut filled = 0;
    for (k, &candidate) in candidates.iter().enumerate() {
        if sample_window(search, candidate, size, &mut windows[filled]) {
            at[filled] = k;
            filled += 1;
            if filled == LANES {
                for (&k, score) in at.iter().zip(score_lanes(&template, &mut windows)) {
                    scores[k] = score;
                }
                filled = 0;
            }
        } else {
            scores[k] = f64::NAN;
        }
    }
    if filled > 0 {
        // The unused lanes hold older (or zero) windows: scored and dropped.
        for (&k, score) in at[..filled]
            .iter()
            .zip(score_lanes(&template, &mut windows))
        {
            scores[k] = score;
        }
    }
}

/// Correlation of `template` (normalised, `n` values) with each of the `LANES` windows
/// (`n` raw samples each; overwritten by their normalised values): `normalised` then the
/// dot product, as `ncc_at` computes them; NaN where a window is flat.
fn score_lanes(template: &[f32], windows: &mut [Vec<f32>; LANES]) -> [f64; LANES] {
    let n = template.len();
    let w: [&[f32]; LANES] = std::array::from_fn(|j| &windows[j][..n]);
    // `Iterator::sum` of f64 starts from -0.0 (the identity of addition); so do these.
    let mut sum = [-0.0f64; LANES];
    for i in 0..n {
        for j in 0..LANES {
            sum[j] += w[j][i] as f64;
        }
    }
    let count = n as f64;
    let mean = sum.map(|s| s / count);
    let mut squares = [-0.0f64; LANES];
    for i in 0..n {
        for j in 0..LANES {
            squares[j] += (w[j][i] as f64 - mean[j]).powi(2);
        }
    }
    let norm = squares.map(f64::sqrt);
    for (window, (&mean, &norm)) in windows.iter_mut().zip(mean.iter().zip(&norm)) {
        for x in window[..n].iter_mut() {
            *x = ((*x as f64 - mean) / norm) as f32;
        }
    }
    let w: [&[f32]; LANES] = std::array::from_fn(|j| &windows[j][..n]);
    let mut dot = [-0.0f64; LANES];
    for (i, &t) in template.iter().enumerate() {
        for j in 0..LANES {
            dot[j] += (t * w[j][i]) as f64;
        }
    }
    std::array::from_fn(|j| if norm[j] > 1e-9 { dot[j] } else { f64::NAN })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::track::ncc_at;

    /// A textured image with flat areas (flat windows) and edges (windows that leave it).
    fn image(width: usize, height: usize, seed: u64) -> Vec<f32> {
        let mut state = seed;
        (0..width * height)
            .map(|i| {
                let (u, v) = (i % width, i / width);
                if u < 20 && v < 20 {
                    return 0.5; // flat
                }
                state = state
                    .wrapping_mul(6364136223846793005)
                    .wrapping_add(1442695040888963407);
                let noise = (state >> 40) as f32 / (1u64 << 24) as f32;
                (u as f32 * 0.13).sin() * (v as f32 * 0.07).cos() + 0.3 * noise
            })
            .collect()
    }

    #[test]
    fn equals_ncc_at_bit_for_bit() {
        let (width, height) = (96, 80);
        let a = image(width, height, 1);
        let b = image(width, height, 2);
        let ta = ImageView {
            data: &a,
            width,
            height,
        };
        let tb = ImageView {
            data: &b,
            width,
            height,
        };
        let mut state = 7u64;
        let mut next = || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        for size in [3, 7, 11, 15] {
            for count in [0, 1, 5, 8, 9, 17, 96] {
                // Candidates inside, across the edges, on the flat corner, and NaN.
                let candidates: Vec<[f64; 2]> = (0..count)
                    .map(|k| match k % 11 {
                        3 => [f64::NAN, 40.0],
                        5 => [8.0 + next(), 9.0 + next()],
                        _ => [next() * width as f64, next() * height as f64],
                    })
                    .collect();
                for point in [[40.3, 35.7], [9.0, 9.0], [2.0, 40.0]] {
                    let mut want = vec![0.0; count];
                    let mut got = vec![1.0; count];
                    ncc_at(&ta, point, &tb, &candidates, size, &mut want);
                    line_ncc(&ta, point, &tb, &candidates, size, &mut got);
                    for (w, g) in want.iter().zip(&got) {
                        assert!(
                            w.to_bits() == g.to_bits() || (w.is_nan() && g.is_nan()),
                            "{w} vs {g}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn scores_its_own_patch_one() {
        let (width, height) = (64, 64);
        let a = image(width, height, 3);
        let ta = ImageView {
            data: &a,
            width,
            height,
        };
        let candidates: Vec<[f64; 2]> = (0..12).map(|k| [30.0 + k as f64 * 0.25, 32.5]).collect();
        let mut scores = vec![0.0; 12];
        line_ncc(&ta, [31.0, 32.5], &ta, &candidates, 11, &mut scores);
        assert!((scores[4] - 1.0).abs() < 1e-5, "{scores:?}");
        assert!(scores.iter().all(|s| s.is_finite() && *s <= 1.0 + 1e-5));
    }
}
