//! Tests of the box search with template weights (`weighted_ncc`).

use super::ncc::{box_search, BoxScratch};
use super::*;
use crate::lsm::ImageView;

const W: usize = 120;
const H: usize = 100;

/// A smooth random texture (sum of sines of the given waves), shifted by `shift` pixels.
fn waves(shift: [f64; 2], waves: &[(f64, f64, f64, f64)]) -> Vec<f32> {
    let mut data = Vec::with_capacity(W * H);
    for v in 0..H {
        for u in 0..W {
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

const LIMB: [(f64, f64, f64, f64); 4] = [
    (0.31, 0.17, 0.0, 40.0),
    (-0.23, 0.29, 1.0, 35.0),
    (0.11, -0.41, 2.0, 25.0),
    (0.47, 0.07, 3.0, 20.0),
];
const BEHIND: [(f64, f64, f64, f64); 4] = [
    (0.19, -0.37, 0.5, 45.0),
    (0.41, 0.23, 1.5, 35.0),
    (-0.29, 0.13, 2.5, 30.0),
    (0.07, 0.49, 3.5, 20.0),
];

fn view(data: &[f32]) -> ImageView<'_> {
    ImageView {
        data,
        width: W,
        height: H,
    }
}

/// The weighted correlation at every shift, computed directly in double precision (the
/// definition in `weighted_ncc`'s docs), with the same bilinear samples.
fn reference(
    template: &ImageView<'_>,
    weights: &ImageView<'_>,
    point: [f64; 2],
    search: &ImageView<'_>,
    prediction: [f64; 2],
    size: usize,
    radius: usize,
) -> Vec<f64> {
    let (mut t, mut w, mut s) = (Vec::new(), Vec::new(), Vec::new());
    assert!(super::ncc::sample_window(template, point, size, &mut t));
    assert!(super::ncc::sample_window(weights, point, size, &mut w));
    let total: f64 = w.iter().map(|&x| x as f64).sum();
    let tm: f64 = t
        .iter()
        .zip(&w)
        .map(|(&a, &b)| a as f64 * b as f64)
        .sum::<f64>()
        / total;
    let mut scores = Vec::new();
    for r in 0..2 * radius + 1 {
        for c in 0..2 * radius + 1 {
            let at = [
                prediction[0] + c as f64 - radius as f64,
                prediction[1] + r as f64 - radius as f64,
            ];
            assert!(super::ncc::sample_window(search, at, size, &mut s));
            let sm: f64 = s
                .iter()
                .zip(&w)
                .map(|(&a, &b)| a as f64 * b as f64)
                .sum::<f64>()
                / total;
            let (mut num, mut vt, mut vs) = (0.0, 0.0, 0.0);
            for i in 0..size * size {
                let (dt, ds, wi) = (t[i] as f64 - tm, s[i] as f64 - sm, w[i] as f64);
                num += wi * dt * ds;
                vt += wi * dt * dt;
                vs += wi * ds * ds;
            }
            scores.push(num / (vt * vs).sqrt());
        }
    }
    scores
}

fn search(
    template: &ImageView<'_>,
    point: [f64; 2],
    current: &ImageView<'_>,
    prediction: [f64; 2],
    radius: usize,
    weights: Option<&ImageView<'_>>,
) -> (super::NccBest, Vec<f64>) {
    let mut scratch = BoxScratch::default();
    let best = box_search(
        template,
        point,
        current,
        prediction,
        15,
        radius,
        weights,
        &mut scratch,
    )
    .expect("inside the image");
    (best, scratch.scores)
}

#[test]
fn uniform_weights_score_every_shift_as_the_plain_search() {
    // Weights of 0.5 everywhere take the weighted path, whose correlation is then the plain
    // one: the same scores at every shift (to single precision's sums), the same peak.
    let (a, b) = (waves([0.0; 2], &LIMB), waves([1.7, -2.3], &LIMB));
    let half = vec![0.5f32; W * H];
    let (ta, tb, th) = (view(&a), view(&b), view(&half));
    for radius in [6, 9] {
        let (point, prediction) = ([60.0, 50.0], [60.4, 49.3]);
        let (plain, plain_scores) = search(&ta, point, &tb, prediction, radius, None);
        let (weighted, scores) = search(&ta, point, &tb, prediction, radius, Some(&th));
        assert_eq!(scores.len(), (2 * radius + 1).pow(2));
        for (i, (x, y)) in plain_scores.iter().zip(&scores).enumerate() {
            assert!(
                (x - y).abs() < 1e-4,
                "radius {radius}, shift {i}: {x} vs {y}"
            );
        }
        assert!((plain.centre[0] - weighted.centre[0]).abs() < 1e-3);
        assert!((plain.centre[1] - weighted.centre[1]).abs() < 1e-3);
        assert!((weighted.centre[0] - 61.7).abs() < 0.3 && (weighted.centre[1] - 47.7).abs() < 0.3);
    }
}

#[test]
fn weights_of_one_are_the_plain_search_to_the_bit() {
    let (a, b) = (waves([0.0; 2], &LIMB), waves([1.3, 2.1], &LIMB));
    let ones = vec![1.0f32; W * H];
    let (ta, tb, to) = (view(&a), view(&b), view(&ones));
    let (plain, plain_scores) = search(&ta, [60.0, 50.0], &tb, [60.3, 50.6], 6, None);
    let (weighted, scores) = search(&ta, [60.0, 50.0], &tb, [60.3, 50.6], 6, Some(&to));
    assert_eq!(plain, weighted);
    assert_eq!(plain_scores, scores);
}

#[test]
fn weighted_scores_match_the_direct_weighted_correlation() {
    // Weights 0 to 1 varying across the patch (a ramp, a hole of zeros, NaN-free), fast rows
    // (radius 6) and general rows (radius 9).
    let (a, b) = (waves([0.0; 2], &LIMB), waves([-2.2, 1.4], &LIMB));
    let weights: Vec<f32> = (0..W * H)
        .map(|i| {
            let (u, v) = ((i % W) as f32, (i / W) as f32);
            if (u - 57.0).abs() < 3.0 && (v - 47.0).abs() < 2.0 {
                0.0
            } else {
                (0.2 + 0.8 * ((u - 40.0) / 40.0).clamp(0.0, 1.0)) * (0.5 + 0.5 * (v / 100.0))
            }
        })
        .collect();
    let (ta, tb, tw) = (view(&a), view(&b), view(&weights));
    for radius in [6, 9] {
        let (point, prediction) = ([60.3, 50.6], [58.1, 52.2]);
        let (_, scores) = search(&ta, point, &tb, prediction, radius, Some(&tw));
        let direct = reference(&ta, &tw, point, &tb, prediction, 15, radius);
        for (i, (x, y)) in scores.iter().zip(&direct).enumerate() {
            assert!(
                (x - y).abs() < 1e-4,
                "radius {radius}, shift {i}: {x} vs {y}"
            );
        }
    }
}

/// A thin limb (7 columns from `edge`, texture `LIMB`) in front of a surface (`BEHIND`),
/// each moved by its own shift, and the limb's mask.
fn scene(limb: [f64; 2], behind: [f64; 2], edge: f64) -> (Vec<f32>, Vec<f32>) {
    let (front, back) = (waves(limb, &LIMB), waves(behind, &BEHIND));
    let mut image = back;
    let mut mask = vec![0.0f32; W * H];
    for v in 0..H {
        for u in 0..W {
            let x = u as f64 - edge - limb[0];
            if (0.0..7.0).contains(&x) {
                image[v * W + u] = front[v * W + u];
                mask[v * W + u] = 1.0;
            }
        }
    }
    (image, mask)
}

#[test]
fn the_limbs_weights_find_its_motion_where_the_plain_search_follows_the_surface_behind() {
    // The template, centred on the limb, holds its 7 columns (moving (4, -3)) and 8 of the
    // surface behind (moving (-3, 2)): the plain search follows the surface behind;
    // weighted by the limb's mask it finds the limb.
    let (a, mask) = scene([0.0; 2], [0.0; 2], 63.0);
    let (b, _) = scene([4.0, -3.0], [-3.0, 2.0], 63.0);
    let (ta, tb, tm) = (view(&a), view(&b), view(&mask));
    let point = [66.0, 50.0];
    let (plain, _) = search(&ta, point, &tb, point, 6, None);
    let (weighted, _) = search(&ta, point, &tb, point, 6, Some(&tm));
    let limb = [point[0] + 4.0, point[1] - 3.0];
    let miss = |c: [f64; 2]| (c[0] - limb[0]).hypot(c[1] - limb[1]);
    assert!(miss(plain.centre) > 3.0, "plain {:?}", plain.centre);
    assert!(
        miss(weighted.centre) < 0.3,
        "weighted {:?}",
        weighted.centre
    );
    assert!(weighted.score > 0.95, "{}", weighted.score);
}

#[test]
fn too_little_weight_is_searched_as_without_weights() {
    // A template with one weighted column (15 of 225 pixels) is searched plainly.
    let (a, b) = (waves([0.0; 2], &LIMB), waves([1.0, 1.0], &LIMB));
    let column: Vec<f32> = (0..W * H)
        .map(|i| if i % W == 60 { 1.0 } else { 0.0 })
        .collect();
    let (ta, tb, tc) = (view(&a), view(&b), view(&column));
    let (plain, plain_scores) = search(&ta, [60.0, 50.0], &tb, [60.0, 50.0], 6, None);
    let (weighted, scores) = search(&ta, [60.0, 50.0], &tb, [60.0, 50.0], 6, Some(&tc));
    assert_eq!(plain, weighted);
    assert_eq!(plain_scores, scores);
}

/// The step's outputs (positions, flags, covariances, correlations).
type Stepped = (Vec<[f64; 2]>, Vec<u8>, Vec<[f64; 4]>, Vec<f64>);

/// One step of `last` from `previous` into `current` with the given weights and options.
fn run_step(
    images: [&ImageView<'_>; 2],
    last: &[[f64; 2]],
    before: &[[f64; 2]],
    weights: [&ImageView<'_>; 2],
    options: &TrackOptions,
) -> Stepped {
    let n = last.len();
    let (mut positions, mut flags) = (vec![[0.0; 2]; n], vec![0u8; n]);
    let (mut covariance, mut correlation) = (vec![[0.0; 4]; n], vec![0.0; n]);
    track_camera(
        images[0],
        images[1],
        last,
        before,
        Some(weights),
        options,
        CameraStep {
            positions: &mut positions,
            flags: &mut flags,
            covariance: &mut covariance,
            correlation: &mut correlation,
        },
    )
    .unwrap();
    (positions, flags, covariance, correlation)
}

#[test]
fn the_step_with_the_weighted_box_tracks_the_limb_over_the_surface_behind() {
    // The whole step (box, weighted match, forward-backward) on the scene above, the limb's
    // masks as the weights: with the plain box the straddling points are lost or follow
    // the surface behind; with the weighted box they are tracked onto the limb's motion.
    let (a, ma) = scene([0.0; 2], [0.0; 2], 63.0);
    let (b, mb) = scene([4.0, -3.0], [-3.0, 2.0], 63.0);
    let (ta, tb, wa, wb) = (view(&a), view(&b), view(&ma), view(&mb));
    let last: Vec<[f64; 2]> = (0..5).map(|k| [66.0, 30.0 + 10.0 * k as f64]).collect();
    let before = vec![[f64::NAN; 2]; last.len()];
    let run = |weighted_box: bool| {
        let options = TrackOptions {
            radius: 6,
            min_correlation: 0.5,
            forward_backward: 0.6,
            weighted_box,
            matching: crate::lsm::MatchOptions {
                size: 15,
                max_shift: 7.0,
                ..TrackOptions::default().matching
            },
        };
        let (positions, flags, _, _) = run_step([&ta, &tb], &last, &before, [&wa, &wb], &options);
        (positions, flags)
    };
    let on_limb = |p: [f64; 2], x: [f64; 2]| (p[0] - x[0] - 4.0).hypot(p[1] - x[1] + 3.0) < 0.3;
    let (plain, plain_flags) = run(false);
    let (weighted, flags) = run(true);
    let plain_held = (0..last.len())
        .filter(|&p| plain_flags[p] == Flag::Tracked as u8 && on_limb(plain[p], last[p]))
        .count();
    assert!(plain_held <= 1, "{plain:?} {plain_flags:?}");
    for p in 0..last.len() {
        assert_eq!(flags[p], Flag::Tracked as u8, "point {p}: {flags:?}");
        assert!(
            on_limb(weighted[p], last[p]),
            "point {p}: {:?}",
            weighted[p]
        );
    }
}

#[test]
fn the_step_ignores_weights_of_one_in_the_box() {
    // Masks of ones: the weighted box changes nothing, to the bit.
    let (a, b) = (waves([0.0; 2], &LIMB), waves([2.3, -1.6], &LIMB));
    let ones = vec![1.0f32; W * H];
    let (ta, tb, to) = (view(&a), view(&b), view(&ones));
    let last = [[40.0, 40.0], [60.5, 50.2], [80.0, 60.0]];
    let before = [[38.0, 41.5], [f64::NAN; 2], [78.0, 62.0]];
    let run = |weighted_box: bool| {
        let options = TrackOptions {
            weighted_box,
            ..TrackOptions::default()
        };
        run_step([&ta, &tb], &last, &before, [&to, &to], &options)
    };
    let (p0, f0, c0, r0) = run(false);
    let (p1, f1, c1, r1) = run(true);
    assert_eq!(f0, f1);
    assert!(f0.iter().all(|&f| f == Flag::Tracked as u8), "{f0:?}");
    for i in 0..3 {
        assert_eq!(p0[i].map(f64::to_bits), p1[i].map(f64::to_bits));
        assert_eq!(c0[i].map(f64::to_bits), c1[i].map(f64::to_bits));
        assert_eq!(r0[i].to_bits(), r1[i].to_bits());
    }
}
