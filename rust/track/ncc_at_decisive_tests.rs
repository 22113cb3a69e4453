//! `ncc_at_decisive` against `ncc_at`: every score it returns is `ncc_at`'s to the bit or
//! -inf where the contract allows, and seeding's test (best sample, peak, rival away from
//! it) decides every row as it does on the exact scores; the estimate is within a tenth
//! of its slack of the exact score wherever it is trusted.

use super::ncc::{fill_window, normalised, sample_window};
use super::ncc_at;
use super::ncc_at::{fill_lane, GROUP};
use super::ncc_at_decisive::ncc_at_decisive;
use super::ncc_at_estimate::{estimate, fill_rows};
use crate::lsm::ImageView;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

const PEAK_WIDTH: usize = 3;

fn view(data: &[f32], width: usize, height: usize) -> ImageView<'_> {
    ImageView {
        data,
        width,
        height,
    }
}

/// Seeding's test on one row (`seeding.py`): the kept sample, or `None`.
fn decide(row: &[f64], min_correlation: f64, uniqueness: f64) -> Option<usize> {
    let s: Vec<f64> = row
        .iter()
        .map(|&x| if x.is_finite() { x } else { f64::NEG_INFINITY })
        .collect();
    // numpy's argmax: the first of the largest.
    let mut best = 0;
    for (i, &x) in s.iter().enumerate() {
        if x > s[best] {
            best = i;
        }
    }
    let peak = s[best];
    let at = |i: isize| -> f64 {
        if i < 0 || i as usize >= s.len() {
            f64::NEG_INFINITY
        } else {
            s[i as usize]
        }
    };
    let mut second = f64::NEG_INFINITY;
    for (i, &x) in s.iter().enumerate() {
        let local = x >= at(i as isize - 1) && x >= at(i as isize + 1) && x.is_finite();
        if local && i.abs_diff(best) > PEAK_WIDTH {
            second = second.max(x);
        }
    }
    (peak >= min_correlation && peak - second >= uniqueness).then_some(best)
}

/// A smooth texture (noise blurred twice by 3 x 3 boxes), `period` > 0 repeating it
/// across (a false match along the line as good as the true one).
fn texture(rng: &mut ChaCha8Rng, w: usize, h: usize, period: usize) -> Vec<f32> {
    let mut a: Vec<f32> = (0..w * h).map(|_| rng.random_range(0.0..255.0)).collect();
    for _ in 0..2 {
        let b = a.clone();
        for y in 1..h - 1 {
            for x in 1..w - 1 {
                let mut s = 0.0;
                for dy in 0..3 {
                    for dx in 0..3 {
                        s += b[(y + dy - 1) * w + x + dx - 1];
                    }
                }
                a[y * w + x] = s / 9.0;
            }
        }
    }
    if period > 0 {
        for y in 0..h {
            for x in period..w {
                a[y * w + x] = a[y * w + x % period];
            }
        }
    }
    a
}

#[test]
fn decisive_scores_decide_seeding_as_the_exact_ones() {
    let mut rng = ChaCha8Rng::seed_from_u64(15);
    let (w, h) = (160usize, 120usize);
    let size = 15;
    let (mut rows, mut kept, mut replaced, mut exact_kept) = (0, 0, 0, 0);
    for case in 0..6 {
        let period = if case % 2 == 1 { 23 } else { 0 };
        let a = texture(&mut rng, w, h, period);
        // The search image: the template image shifted by (dx, dy) with a little noise.
        let (dx, dy) = (rng.random_range(-6..=6i64), rng.random_range(-6..=6i64));
        let noise = [0.0f32, 2.0, 8.0][case % 3];
        let b: Vec<f32> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as i64 - dx, (i / w) as i64 - dy);
                let v =
                    a[y.clamp(0, h as i64 - 1) as usize * w + x.clamp(0, w as i64 - 1) as usize];
                v + noise * rng.random_range(-1.0..1.0f32)
            })
            .collect();
        let ta = view(&a, w, h);
        let tb = view(&b, w, h);
        for _ in 0..60 {
            let point = [rng.random_range(10.0..150.0), rng.random_range(10.0..110.0)];
            // 96 samples along a line through the true match (or near it), some leaving
            // the image.
            let angle: f64 = rng.random_range(0.0..std::f64::consts::PI);
            let step = rng.random_range(0.1..1.2);
            let centre = [
                point[0] + dx as f64 + rng.random_range(-1.0..1.0),
                point[1] + dy as f64 + rng.random_range(-1.0..1.0),
            ];
            let offset = rng.random_range(-40.0..40.0);
            let candidates: Vec<[f64; 2]> = (0..96)
                .map(|i| {
                    let t = (i as f64 - 48.0) * step + offset * step;
                    [centre[0] + t * angle.cos(), centre[1] + t * angle.sin()]
                })
                .collect();
            let mut exact = vec![0.0; 96];
            ncc_at(&ta, point, &tb, &candidates, size, &mut exact);
            for &(min_correlation, uniqueness) in
                &[(0.75, 0.1), (0.5, 0.1), (0.9, 0.05), (0.3, 0.3)]
            {
                let mut got = vec![0.0; 96];
                ncc_at_decisive(
                    &ta,
                    point,
                    &tb,
                    &candidates,
                    size,
                    min_correlation,
                    uniqueness,
                    &mut got,
                );
                let peak = exact
                    .iter()
                    .filter(|x| x.is_finite())
                    .fold(f64::NEG_INFINITY, |m, &x| m.max(x));
                for (&e, &g) in exact.iter().zip(&got) {
                    if g == f64::NEG_INFINITY && e.is_finite() {
                        replaced += 1;
                        assert!(
                            peak < min_correlation || e < peak - uniqueness,
                            "replaced {e} in a row with peak {peak}"
                        );
                    } else {
                        assert_eq!(e.to_bits(), g.to_bits(), "{e} {g}");
                    }
                }
                let decision = decide(&exact, min_correlation, uniqueness);
                assert_eq!(decide(&got, min_correlation, uniqueness), decision);
                rows += 1;
                kept += decision.is_some() as usize;
                exact_kept += (peak >= min_correlation) as usize;
            }
        }
    }
    // Not vacuous: rows kept and refused, rows with a peak but no kept sample (a rival), and
    // scores replaced.
    assert!(kept > rows / 10 && kept < rows * 9 / 10, "{kept} of {rows}");
    assert!(exact_kept > kept, "{exact_kept} {kept}");
    assert!(replaced > rows * 30, "{replaced} of {rows} rows");
}

#[test]
fn low_contrast_and_flat_windows_are_scored_exactly() {
    // A flat block (NaN) and a block of tiny contrast (the estimate is not trusted): both
    // come back as `ncc_at`'s whatever the threshold.
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let (w, h) = (90usize, 60usize);
    let a = texture(&mut rng, w, h, 0);
    let b: Vec<f32> = (0..w * h)
        .map(|i| match i % w {
            0..=29 => 7.0,
            30..=59 => 200.0 + rng.random_range(-0.01..0.01f32),
            _ => a[i],
        })
        .collect();
    let ta = view(&a, w, h);
    let tb = view(&b, w, h);
    let candidates: Vec<[f64; 2]> = (0..96).map(|i| [8.0 + i as f64 * 0.6, 30.3]).collect();
    let mut exact = vec![0.0; 96];
    ncc_at(&ta, [45.0, 30.0], &tb, &candidates, 15, &mut exact);
    let mut got = vec![0.0; 96];
    ncc_at_decisive(&ta, [45.0, 30.0], &tb, &candidates, 15, -1.0, 0.1, &mut got);
    let (mut low, mut flat) = (0, 0);
    for (k, (&e, &g)) in exact.iter().zip(&got).enumerate() {
        let u = candidates[k][0];
        if u + 8.0 < 30.0 {
            assert!(e.is_nan() && g.is_nan(), "{u}: {e} {g}");
            flat += 1;
        } else if u - 7.0 >= 30.0 && u + 8.0 < 60.0 {
            assert!(e.is_finite());
            assert_eq!(e.to_bits(), g.to_bits());
            low += 1;
        }
    }
    assert!(low > 10 && flat > 10, "{low} {flat}");
}

#[test]
fn trusted_estimates_are_within_a_tenth_of_the_slack() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let (w, h) = (80usize, 80usize);
    let (mut trusted, mut worst) = (0, 0.0f64);
    for case in 0..40 {
        // Textures of every contrast on every offset, down to where the estimate is refused.
        let scale = 10f32.powi(-(case % 8));
        let base = [0.0f32, 50.0, 250.0][case as usize % 3];
        let a: Vec<f32> = texture(&mut rng, w, h, 0)
            .iter()
            .map(|&x| base + scale * x)
            .collect();
        let b: Vec<f32> = texture(&mut rng, w, h, 0)
            .iter()
            .map(|&x| base + scale * x)
            .collect();
        let ta = view(&a, w, h);
        let tb = view(&b, w, h);
        let mut values = Vec::new();
        assert!(sample_window(&ta, [40.0, 40.0], 15, &mut values));
        let Some(template) = normalised(&values) else {
            continue;
        };
        let sum: f64 = template.iter().map(|&t| t as f64).sum();
        let wide: Vec<f64> = template.iter().map(|&t| t as f64).collect();
        let mut window = vec![0.0f32; 225];
        for _ in 0..50 {
            let c = [rng.random_range(9.0..70.0), rng.random_range(9.0..70.0)];
            fill_window(&tb, c, 15, &mut window);
            let mut exact = [0.0];
            ncc_at(&ta, [40.0, 40.0], &tb, &[c], 15, &mut exact);
            let plain = estimate::<false>(&wide, sum, &window);
            // Fused products round as the separate ones (a product of two `f32`s is exact).
            let fused = estimate::<true>(&wide, sum, &window);
            assert_eq!(plain.map(f64::to_bits), fused.map(f64::to_bits));
            if let Some(e) = plain {
                trusted += 1;
                worst = worst.max((e - exact[0]).abs());
            }
        }
    }
    assert!(trusted > 500, "{trusted}");
    assert!(worst < 1e-6, "{worst}");
}

#[test]
fn blocks_of_columns_fill_as_the_window_does_to_the_bit() {
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let (w, h) = (60usize, 50usize);
    let a: Vec<f32> = (0..w * h).map(|_| rng.random_range(0.0..255.0)).collect();
    let image = view(&a, w, h);
    for side in (3..=31).step_by(2) {
        for _ in 0..20 {
            let half = (side / 2) as f64;
            let c = [
                rng.random_range(half..w as f64 - half - 2.0),
                rng.random_range(half..h as f64 - half - 2.0),
            ];
            let (mut want, mut got) = (vec![0.0f32; side * side], vec![1.0f32; side * side]);
            fill_window(&image, c, side, &mut want);
            fill_rows(&image, c, side, &mut got);
            assert!(
                want.iter()
                    .zip(&got)
                    .all(|(x, y)| x.to_bits() == y.to_bits()),
                "side {side}"
            );
            // The exact path's pixel-major lanes: the same samples in lane 5, the other
            // lanes untouched.
            let mut lanes = vec![-1.0f32; side * side * GROUP];
            fill_lane(&image, c, side, &mut lanes, 5);
            for (i, pixel) in lanes.chunks_exact(GROUP).enumerate() {
                assert_eq!(
                    pixel[5].to_bits(),
                    want[i].to_bits(),
                    "side {side} pixel {i}"
                );
                assert!(pixel.iter().enumerate().all(|(j, &x)| j == 5 || x == -1.0));
            }
        }
    }
}
