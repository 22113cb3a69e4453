use super::*;
use crate::lsm::ImageView;

/// A smooth random texture (sum of sines), shifted by `shift` pixels.
fn texture(width: usize, height: usize, shift: [f64; 2]) -> Vec<f32> {
    let waves = [
        (0.31, 0.17, 0.0, 40.0),
        (-0.23, 0.29, 1.0, 35.0),
        (0.11, -0.41, 2.0, 25.0),
        (0.47, 0.07, 3.0, 20.0),
        (0.05, 0.53, 4.0, 15.0),
    ];
    let mut data = Vec::with_capacity(width * height);
    for v in 0..height {
        for u in 0..width {
            let (x, y) = (u as f64 - shift[0], v as f64 - shift[1]);
            let g: f64 = waves
                .iter()
                .map(|&(a, b, p, amp)| amp * (a * x + b * y + p).sin())
                .sum();
            data.push((128.0 + g) as f32);
        }
    }
    data
}

fn step(
    previous: &[f32],
    current: &[f32],
    last: &[[f64; 2]],
    before: &[[f64; 2]],
) -> (Vec<[f64; 2]>, Vec<u8>) {
    let (w, h) = (120, 100);
    let prev = ImageView {
        data: previous,
        width: w,
        height: h,
    };
    let cur = ImageView {
        data: current,
        width: w,
        height: h,
    };
    let n = last.len();
    let mut positions = vec![[0.0; 2]; n];
    let mut flags = vec![0u8; n];
    let mut covariance = vec![[0.0; 4]; n];
    let mut correlation = vec![0.0; n];
    track_camera(
        &prev,
        &cur,
        last,
        before,
        None,
        &TrackOptions::default(),
        CameraStep {
            positions: &mut positions,
            flags: &mut flags,
            covariance: &mut covariance,
            correlation: &mut correlation,
        },
    )
    .unwrap();
    (positions, flags)
}

#[test]
fn tracks_a_known_shift_with_prediction() {
    // Moved (11.3, -9.6) px; the prediction from the last two positions says (11, -10).
    let shift = [11.3, -9.6];
    let (a, b) = (texture(120, 100, [0.0; 2]), texture(120, 100, shift));
    let last = [[35.0, 60.0], [50.2, 55.7], [70.0, 65.0]];
    let before: Vec<_> = last.iter().map(|p| [p[0] - 11.0, p[1] + 10.0]).collect();
    let (positions, flags) = step(&a, &b, &last, &before);
    for (p, x) in last.iter().enumerate() {
        assert_eq!(flags[p], Flag::Tracked as u8);
        let e = (positions[p][0] - x[0] - shift[0]).hypot(positions[p][1] - x[1] - shift[1]);
        assert!(e < 0.02, "point {p}: error {e}");
    }
    // Without the prediction the shift lies outside the box: not tracked, and flagged.
    let (_, flags) = step(&a, &b, &last, &[[f64::NAN; 2]; 3]);
    assert!(flags.iter().all(|&f| f != Flag::Tracked as u8), "{flags:?}");
}

#[test]
fn flags_border_unseeded_and_occlusion() {
    let (a, mut b) = (texture(120, 100, [0.0; 2]), texture(120, 100, [1.0, 0.5]));
    // Occlude the neighbourhood of (60, 50) with another texture.
    let other = texture(120, 100, [37.0, 11.0]);
    for v in 35..65 {
        for u in 45..75 {
            b[v * 120 + u] = 255.0 - other[v * 120 + u];
        }
    }
    let last = [
        [60.0, 50.0],
        [3.0, 50.0],
        [f64::NAN, f64::NAN],
        [20.0, 20.0],
    ];
    let (positions, flags) = step(&a, &b, &last, &[[f64::NAN; 2]; 4]);
    assert_eq!(flags[0], Flag::LowCorrelation as u8);
    assert_eq!(flags[1], Flag::ImageBorder as u8);
    assert_eq!(flags[2], Flag::NotSeeded as u8);
    assert_eq!(flags[3], Flag::Tracked as u8);
    assert!(positions[0][0].is_nan() && positions[3][0].is_finite());
}

#[test]
fn ncc_at_peaks_at_the_match() {
    let (a, b) = (texture(120, 100, [0.0; 2]), texture(120, 100, [2.5, 1.0]));
    let (ta, tb) = (
        ImageView {
            data: &a,
            width: 120,
            height: 100,
        },
        ImageView {
            data: &b,
            width: 120,
            height: 100,
        },
    );
    let candidates: Vec<[f64; 2]> = (0..11).map(|k| [55.0 + 0.5 * k as f64, 51.0]).collect();
    let mut scores = vec![0.0; candidates.len()];
    ncc_at(&ta, [55.0, 50.0], &tb, &candidates, 11, &mut scores);
    let best = (0..11)
        .max_by(|&i, &j| scores[i].total_cmp(&scores[j]))
        .unwrap();
    assert_eq!(best, 5, "{scores:?}");
    assert!(scores[5] > 0.999);
}

#[test]
fn box_search_scores_every_shift_as_ncc_does() {
    // The row-at-once dot products of the box search against the correlation computed
    // patch by patch (`ncc_at`, a plain normalised dot product) at every integer shift.
    let (a, b) = (texture(120, 100, [0.0; 2]), texture(120, 100, [1.7, -2.3]));
    let view = |data| ImageView {
        data,
        width: 120,
        height: 100,
    };
    let (ta, tb) = (view(&a), view(&b));
    let (point, prediction, size, radius) = ([60.0, 50.0], [60.4, 49.3], 15, 6);
    let mut scratch = super::ncc::BoxScratch::default();
    let best = super::ncc::box_search(
        &ta,
        point,
        &tb,
        prediction,
        size,
        radius,
        None,
        &mut scratch,
    )
    .unwrap();
    let shifts = 2 * radius + 1;
    let candidates: Vec<[f64; 2]> = (0..shifts * shifts)
        .map(|i| {
            let (r, c) = (i / shifts, i % shifts);
            [
                prediction[0] + c as f64 - radius as f64,
                prediction[1] + r as f64 - radius as f64,
            ]
        })
        .collect();
    let mut scores = vec![0.0; candidates.len()];
    ncc_at(&ta, point, &tb, &candidates, size, &mut scores);
    let top = (0..scores.len())
        .max_by(|&i, &j| scores[i].total_cmp(&scores[j]))
        .unwrap();
    assert!(
        (best.score - scores[top]).abs() < 1e-4,
        "{} vs {}",
        best.score,
        scores[top]
    );
    // The integer peak is the shift nearest the true one; the parabola refines it.
    let at = candidates[top];
    assert!((best.centre[0] - at[0]).abs() <= 0.5 && (best.centre[1] - at[1]).abs() <= 0.5);
    assert!(
        (best.centre[0] - 61.7).abs() < 0.3 && (best.centre[1] - 47.7).abs() < 0.3,
        "{:?}",
        best.centre
    );
}

#[test]
fn box_search_fast_rows_score_as_the_general_rows_do() {
    // Radius 6 runs the fixed-width rows of 16 lanes (13 shifts), radius 9 those of 24
    // (19 shifts; the general loop: `fixed_width_shift_rows_equal_the_general_rows_to_the_bit`):
    // the shared shifts must score the same (the dot products run in the same order; the
    // window's summed-area tables differ in their last bits).
    let (a, b) = (texture(120, 100, [0.0; 2]), texture(120, 100, [1.3, 2.1]));
    let view = |data| ImageView {
        data,
        width: 120,
        height: 100,
    };
    let (ta, tb) = (view(&a), view(&b));
    let (point, prediction, size) = ([60.0, 50.0], [60.3, 50.6], 15);
    let mut fast = super::ncc::BoxScratch::default();
    let mut general = super::ncc::BoxScratch::default();
    let best =
        super::ncc::box_search(&ta, point, &tb, prediction, size, 6, None, &mut fast).unwrap();
    let wide =
        super::ncc::box_search(&ta, point, &tb, prediction, size, 9, None, &mut general).unwrap();
    assert_eq!(fast.scores.len(), 13 * 13);
    assert_eq!(general.scores.len(), 19 * 19);
    for r in 0..13 {
        for c in 0..13 {
            let (a, b) = (
                fast.scores[r * 13 + c],
                general.scores[(r + 3) * 19 + c + 3],
            );
            assert!((a - b).abs() < 1e-9, "shift {r} {c}: {a} vs {b}");
        }
    }
    assert!(
        (best.centre[0] - wide.centre[0]).abs() < 1e-6
            && (best.centre[1] - wide.centre[1]).abs() < 1e-6
    );
    assert!(
        (best.centre[0] - 61.3).abs() < 0.3 && (best.centre[1] - 52.1).abs() < 0.3,
        "{:?}",
        best.centre
    );
}

#[test]
fn fixed_width_shift_rows_equal_the_general_rows_to_the_bit() {
    // The box search's dot products at every shift: the rows of two registers (up to 16
    // shifts), of three (up to 24: the coarse-to-fine first step's radius 8) and the
    // general loop must give the same bits (same terms, same order). Random windows over
    // several magnitudes, radii 1-12 (12 takes the general loop), odd sizes 3-21.
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(41);
    let mut checked = [0usize; 3];
    for size in (3..=21).step_by(2) {
        for radius in 1..=12 {
            let side = size + 2 * radius;
            let shifts = 2 * radius + 1;
            for _ in 0..3 {
                let window: Vec<f32> = (0..side * side)
                    .map(|_| rng.random_range(-1.0..1.0f32) * rng.random_range(1.0..300.0f32))
                    .collect();
                let template: Vec<f32> = (0..size * size)
                    .map(|_| rng.random_range(-0.2..0.2f32))
                    .collect();
                let (mut padded, mut fast) = (Vec::new(), Vec::new());
                super::ncc::shift_dots(&window, side, &template, size, &mut padded, &mut fast);
                let mut general = vec![0.0f32; shifts * shifts];
                super::ncc::general_rows(&window, side, &template, size, &mut general);
                assert_eq!(fast.len(), general.len());
                for (k, (a, b)) in fast.iter().zip(&general).enumerate() {
                    assert_eq!(
                        a.to_bits(),
                        b.to_bits(),
                        "size {size} radius {radius} shift {k}"
                    );
                }
                checked[usize::from(shifts > 16) + usize::from(shifts > 24)] += 1;
            }
        }
    }
    assert!(checked.iter().all(|&c| c > 0), "{checked:?}");
}
