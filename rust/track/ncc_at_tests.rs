//! `ncc_at`'s grouped scores against one candidate at a time, bit for bit; the test that
//! decides when a product by the inverse norm may round to another `f32` than the quotient.

use super::ncc::{normalised, sample_window};
use super::ncc_at;
use super::ncc_at::{near_f32_tie, score_group, GROUP};
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
    // some outside (NaN), in runs of every length (groups of eight and their remainders).
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
        let k = case % 20;
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
    assert!(nan > 50 && scored > 800, "{nan} NaN, {scored} scored");
}

#[test]
fn a_product_by_the_inverse_rounds_as_the_quotient_unless_flagged() {
    // Quotients placed on and around the midpoints between neighbouring f32s (where the
    // product by the inverse, a few f64 units off, can round to the other f32), across
    // binades and signs, and random ones: every product the test lets through rounds to
    // the quotient's f32. Some unflagged products would round otherwise: the test matters.
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let (mut flagged, mut apart, mut through) = (0, 0, 0);
    for case in 0..200_000 {
        let norm: f64 = 10f64.powf(rng.random_range(-3.0..4.0));
        let d = if case % 4 == 3 {
            rng.random_range(-1.0..1.0) * norm
        } else {
            let f = (rng.random_range(-1.0f32..1.0) * 2f32.powi(-rng.random_range(0..30)))
                .clamp(-0.999, 0.999);
            let up = f32::from_bits(f.to_bits() + 1);
            let mid = (f as f64 + up as f64) / 2.0;
            let d = mid * norm;
            f64::from_bits(d.to_bits().wrapping_add_signed(rng.random_range(-40..=40)))
        };
        let quotient = (d / norm) as f32;
        let product = d * (1.0 / norm);
        if (product as f32).to_bits() != quotient.to_bits() {
            apart += 1;
            assert!(near_f32_tie(product), "{d} / {norm}: {product} not flagged");
        }
        if near_f32_tie(product) {
            flagged += 1;
        } else {
            through += 1;
        }
    }
    assert!(
        apart > 100 && through > 60_000 && flagged > 10_000,
        "{apart} apart, {flagged} flagged, {through} through"
    );
    // Subnormal f32 results and zero.
    assert!(near_f32_tie(1e-40) && near_f32_tie(-1e-39));
    assert!(!near_f32_tie(0.0) && !near_f32_tie(0.5) && !near_f32_tie(-0.25));
}

#[test]
fn groups_that_fall_back_to_the_division_score_as_one_at_a_time() {
    // Random windows scored eight at a time against one alone (`normalised` and the dot
    // product), to the bit; among ~70 M values a few lie near an f32 midpoint, so some
    // groups take the division's path (counted: the test must see it).
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let n = 15 * 15;
    let template = normalised(
        &(0..n)
            .map(|_| rng.random_range(0.0f32..255.0))
            .collect::<Vec<_>>(),
    )
    .expect("textured");
    let mut windows = vec![0.0f32; GROUP * n];
    let mut fell_back = 0;
    for _ in 0..40_000 {
        windows
            .iter_mut()
            .for_each(|x| *x = rng.random_range(0.0f32..255.0));
        let got = score_group(&template, &windows);
        let mut tie = false;
        for (j, &g) in got.iter().enumerate() {
            let lane: Vec<f32> = (0..n).map(|i| windows[i * GROUP + j]).collect();
            let mean = lane.iter().map(|&x| x as f64).sum::<f64>() / n as f64;
            let norm = lane
                .iter()
                .map(|&x| (x as f64 - mean).powi(2))
                .sum::<f64>()
                .sqrt();
            tie |= lane
                .iter()
                .any(|&x| near_f32_tie((x as f64 - mean) * (1.0 / norm)));
            let s = normalised(&lane).expect("textured");
            let want: f64 = template.iter().zip(&s).map(|(a, b)| (a * b) as f64).sum();
            assert_eq!(g.to_bits(), want.to_bits(), "{g} vs {want}");
        }
        fell_back += tie as usize;
    }
    assert!(fell_back > 0, "no group fell back");
}
