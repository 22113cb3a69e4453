//! The box search's two-pass summed-area tables, its branch-free scores and its
//! template buffer against what they replaced, bit for bit.

use super::{
    normalised, normalised_into, plain_scores, shift_dots, summed_area_tables,
    summed_area_tables_single_pass,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn bits(x: &[f64]) -> Vec<u64> {
    x.iter().map(|v| v.to_bits()).collect()
}

/// A random window over several magnitudes, with runs of zeros and negative zeros (a flat
/// corner: zero variance, and running sums that cancel to zero).
fn window(rng: &mut ChaCha8Rng, side: usize) -> Vec<f32> {
    let scale = rng.random_range(0.01f32..500.0);
    (0..side * side)
        .map(|i| match i % 11 {
            0 => -0.0,
            1 => 0.0,
            _ if i < side * 2 && rng.random_bool(0.5) => 0.0,
            _ => rng.random_range(-1.0f32..1.0) * scale,
        })
        .collect()
}

/// The score loop the box search ran before (a branch per shift), scores and first best.
fn scores_one_by_one(
    sum: &[f64],
    square: &[f64],
    dots: &[f32],
    side: usize,
    size: usize,
) -> (Vec<f64>, f64, (usize, usize)) {
    let (stride, shifts) = (side + 1, side + 1 - size);
    let n = (size * size) as f64;
    let box_sum = |table: &[f64], r: usize, c: usize| {
        table[(r + size) * stride + c + size]
            - table[r * stride + c + size]
            - table[(r + size) * stride + c]
            + table[r * stride + c]
    };
    let mut scores = Vec::new();
    let (mut best, mut best_at) = (f64::NEG_INFINITY, (shifts / 2, shifts / 2));
    for r in 0..shifts {
        for c in 0..shifts {
            let s = box_sum(sum, r, c);
            let ss = box_sum(square, r, c);
            let variance = ss - s * s / n;
            let score = if variance > 1e-9 {
                dots[r * shifts + c] as f64 / variance.sqrt()
            } else {
                0.0
            };
            scores.push(score);
            if score > best {
                best = score;
                best_at = (r, c);
            }
        }
    }
    (scores, best, best_at)
}

#[test]
fn two_pass_summed_area_tables_equal_the_single_pass_to_the_bit() {
    // Sides below, at and above multiples of the rows run side by side (1-40), so that the
    // remainder rows run too; reused buffers of other sizes.
    let mut rng = ChaCha8Rng::seed_from_u64(43);
    let (mut sum, mut square) = (Vec::new(), Vec::new());
    for side in 1..=40 {
        for _ in 0..4 {
            let w = window(&mut rng, side);
            summed_area_tables(&w, side, &mut sum, &mut square);
            let (want_sum, want_square) = summed_area_tables_single_pass(&w, side);
            assert_eq!(bits(&sum), bits(&want_sum), "sums, side {side}");
            assert_eq!(bits(&square), bits(&want_square), "squares, side {side}");
        }
    }
}

#[test]
fn branch_free_scores_equal_the_scores_one_by_one_to_the_bit() {
    // Odd sizes 3-21, radii 1-12, windows with flat parts (variance at or below the
    // threshold: score 0) and textured ones; the best shift found after the scores must be
    // the first best in row-major order, as before.
    let mut rng = ChaCha8Rng::seed_from_u64(47);
    let (mut sum, mut square, mut padded, mut dots, mut scores) =
        (Vec::new(), Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let mut flat = 0;
    for size in (3..=21).step_by(2) {
        for radius in 1..=12 {
            let side = size + 2 * radius;
            let shifts = 2 * radius + 1;
            for case in 0..3 {
                let mut w = window(&mut rng, side);
                if case == 2 {
                    // A flat band across the top: the shifts there have no variance.
                    w[..side * (size + 1)].fill(7.0);
                }
                let t: Vec<f32> = (0..size * size)
                    .map(|_| rng.random_range(-1.0f32..1.0))
                    .collect();
                let template = normalised(&t).expect("textured template");
                summed_area_tables(&w, side, &mut sum, &mut square);
                shift_dots(&w, side, &template, size, &mut padded, &mut dots);
                plain_scores(&sum, &square, &dots, side, size, &mut scores);
                let (want, want_best, want_at) =
                    scores_one_by_one(&sum, &square, &dots, side, size);
                assert_eq!(bits(&scores), bits(&want), "size {size} radius {radius}");
                let (mut best, mut at) = (f64::NEG_INFINITY, (radius, radius));
                for (i, &s) in scores.iter().enumerate() {
                    if s > best {
                        best = s;
                        at = (i / shifts, i % shifts);
                    }
                }
                assert_eq!((best.to_bits(), at), (want_best.to_bits(), want_at));
                flat += scores.iter().filter(|&&s| s == 0.0).count();
            }
        }
    }
    assert!(flat > 0, "no flat shift was checked");
}

#[test]
fn template_into_a_kept_buffer_equals_the_allocated_one() {
    let mut rng = ChaCha8Rng::seed_from_u64(53);
    let mut out = Vec::new();
    for n in [9usize, 25, 225, 289, 17] {
        let values: Vec<f32> = (0..n).map(|_| rng.random_range(0.0f32..255.0)).collect();
        assert!(normalised_into(&values, &mut out));
        let want = normalised(&values).expect("textured");
        assert_eq!(
            out.iter().map(|v| v.to_bits()).collect::<Vec<_>>(),
            want.iter().map(|v| v.to_bits()).collect::<Vec<_>>()
        );
        // A flat patch: refused, as `normalised` refuses it.
        assert!(!normalised_into(&vec![3.5; n], &mut out));
        assert!(normalised(&vec![3.5; n]).is_none());
    }
}
