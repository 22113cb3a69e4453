//! `ncc_at`'s grouped scores against one candidate at a time, bit for bit.

use super::ncc::{normalised, sample_window};
use super::ncc_at;
use crate::lsm::ImageView;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// One candidate at a time, as `ncc_at` scored before it grouped them.
fn one_by_one(
    template_image: &ImageView<'_>,
    point: [f64; 2],
    search: &ImageView<'_>,
    candidates: &[[f64; 2]],
    size: usize,
) -> Vec<f64> {
    let mut values = Vec::new();
    let template = if sample_window(template_image, point, size, &mut values) {
        normalised(&values)
    } else {
        None
    };
    candidates
        .iter()
        .map(|&candidate| match &template {
            Some(t) if sample_window(search, candidate, size, &mut values) => {
                match normalised(&values) {
                    Some(s) => t.iter().zip(&s).map(|(a, b)| (a * b) as f64).sum(),
                    None => f64::NAN,
                }
            }
            _ => f64::NAN,
        })
        .collect()
}

#[test]
fn grouped_candidate_scores_equal_one_at_a_time_to_the_bit() {
    // Noise images with a flat block (flat windows score NaN) and candidates anywhere,
    // some outside (NaN), in runs of every length (groups of four and their remainders).
    let mut rng = ChaCha8Rng::seed_from_u64(31);
    let (w, h) = (70usize, 50usize);
    let image = |rng: &mut ChaCha8Rng| -> Vec<f32> {
        (0..w * h)
            .map(|i| {
                if i % w < 20 && i / w < 20 {
                    7.0
                } else {
                    rng.random_range(0.0..255.0)
                }
            })
            .collect()
    };
    let (a, b) = (image(&mut rng), image(&mut rng));
    let (ta, tb) = (
        ImageView {
            data: &a,
            width: w,
            height: h,
        },
        ImageView {
            data: &b,
            width: w,
            height: h,
        },
    );
    let mut nan = 0;
    let mut scored = 0;
    for case in 0..400 {
        let size = [3usize, 7, 11, 15][case % 4];
        let point = [
            rng.random_range(-3.0..w as f64 + 3.0),
            rng.random_range(-3.0..h as f64 + 3.0),
        ];
        let k = case % 11;
        let candidates: Vec<[f64; 2]> = (0..k)
            .map(|_| {
                let c = [
                    rng.random_range(-3.0..w as f64 + 3.0),
                    rng.random_range(-3.0..h as f64 + 3.0),
                ];
                if rng.random_bool(0.2) {
                    [c[0].round(), c[1].round()]
                } else if rng.random_bool(0.1) {
                    [10.0, 10.0]
                } else {
                    c
                }
            })
            .collect();
        let want = one_by_one(&ta, point, &tb, &candidates, size);
        let mut got = vec![0.0; k];
        ncc_at(&ta, point, &tb, &candidates, size, &mut got);
        for (g, x) in got.iter().zip(&want) {
            assert_eq!(
                g.to_bits(),
                x.to_bits(),
                "case {case} size {size}: {g} vs {x}"
            );
            if x.is_nan() {
                nan += 1;
            } else {
                scored += 1;
            }
        }
    }
    assert!(nan > 50 && scored > 500, "{nan} NaN, {scored} scored");
}
