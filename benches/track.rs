//! The tracker's box search and frame step with template weights (rust/track/weighted_ncc.rs):
//! 1,000 points of a 640x480 procedural texture moved (2.3, -1.6) px, 15 px patches, radius
//! 6 (the tracker's defaults), one thread. "plain": no weights; "ones": weights all 1 (the
//! plain search after a scan of the weights); "cut": every template holds a weight edge
//! (vertical stripes of zeros 20 px apart), the weighted search. The step: the whole frame
//! step (box, weighted match, forward-backward) with the cut weights, plain box and
//! weighted box. "step_8_cameras_2_threads": the step of 8 cameras in one call
//! ([`track_cameras`]: one parallel pass over every camera's views) at two threads, the
//! tracker's shape on big16: 1,000 rows per camera of which a quarter are seeded (the
//! others NaN: views the point does not have), the cut weights.

use criterion::{criterion_group, criterion_main, Criterion};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

use _core::lsm::{ImageView, MatchOptions};
use _core::track::{
    box_search_scores, track_camera, track_cameras, CameraFrames, CameraStep, TrackOptions,
};

const WIDTH: usize = 640;
const HEIGHT: usize = 480;

fn render(shift: [f64; 2], rng: &mut ChaCha8Rng) -> Vec<f32> {
    let waves: Vec<([f64; 2], f64)> = {
        let mut r = ChaCha8Rng::seed_from_u64(7);
        (0..30)
            .map(|_| {
                let angle = r.random_range(0.0..std::f64::consts::TAU);
                let frequency = r.random_range(0.2..1.0);
                (
                    [frequency * angle.cos(), frequency * angle.sin()],
                    r.random_range(0.0..std::f64::consts::TAU),
                )
            })
            .collect()
    };
    let amplitude = 35.0 * (2.0f64 / 30.0).sqrt();
    (0..WIDTH * HEIGHT)
        .map(|i| {
            let (u, v) = ((i % WIDTH) as f64 - shift[0], (i / WIDTH) as f64 - shift[1]);
            let g: f64 = waves
                .iter()
                .map(|(w, p)| (w[0] * u + w[1] * v + p).sin())
                .sum();
            (128.0 + amplitude * g + rng.random_range(-2.0..2.0)) as f32
        })
        .collect()
}

fn view(data: &[f32]) -> ImageView<'_> {
    ImageView {
        data,
        width: WIDTH,
        height: HEIGHT,
    }
}

fn track(c: &mut Criterion) {
    let mut rng = ChaCha8Rng::seed_from_u64(19);
    let (shift, prediction_error) = ([2.3, -1.6], [1.0, -1.0]);
    let previous = render([0.0; 2], &mut rng);
    let current = render(shift, &mut rng);
    let ones = vec![1.0f32; WIDTH * HEIGHT];
    let cut: Vec<f32> = (0..WIDTH * HEIGHT)
        .map(|i| if (i % WIDTH) % 20 < 3 { 0.0 } else { 1.0 })
        .collect();
    let n = 1000;
    let points: Vec<[f64; 2]> = (0..n)
        .map(|_| {
            [
                rng.random_range(40.0..600.0f64).round(),
                rng.random_range(40.0..440.0f64).round(),
            ]
        })
        .collect();
    let before: Vec<[f64; 2]> = points
        .iter()
        .map(|p| {
            [
                p[0] - shift[0] - prediction_error[0],
                p[1] - shift[1] - prediction_error[1],
            ]
        })
        .collect();
    let (pv, cv) = (view(&previous), view(&current));
    let (ov, kv) = (view(&ones), view(&cut));
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let mut group = c.benchmark_group("track_1000_points_15px_radius_6");
    group.sample_size(10);
    for (label, weights) in [("plain", None), ("ones", Some(&ov)), ("cut", Some(&kv))] {
        group.bench_function(format!("box_search_{label}"), |b| {
            b.iter(|| {
                points
                    .iter()
                    .zip(&before)
                    .filter_map(|(&p, &q)| {
                        let prediction = [2.0 * p[0] - q[0], 2.0 * p[1] - q[1]];
                        box_search_scores(&pv, black_box(p), &cv, prediction, 15, 6, weights)
                            .map(|(best, _)| best.score)
                    })
                    .sum::<f64>()
            })
        });
    }
    for weighted_box in [false, true] {
        let options = TrackOptions {
            matching: MatchOptions {
                size: 15,
                max_iterations: 8,
                max_shift: 7.0,
                ..TrackOptions::default().matching
            },
            radius: 6,
            min_correlation: 0.5,
            forward_backward: 0.6,
            weighted_box,
        };
        let mut positions = vec![[0.0; 2]; n];
        let mut flags = vec![0u8; n];
        let mut covariance = vec![[0.0; 4]; n];
        let mut correlation = vec![0.0; n];
        let label = if weighted_box {
            "step_cut_weighted_box"
        } else {
            "step_cut_plain_box"
        };
        group.bench_function(label, |b| {
            b.iter(|| {
                pool.install(|| {
                    track_camera(
                        &pv,
                        &cv,
                        black_box(&points),
                        &before,
                        Some([&kv, &kv]),
                        &options,
                        CameraStep {
                            positions: &mut positions,
                            flags: &mut flags,
                            covariance: &mut covariance,
                            correlation: &mut correlation,
                        },
                    )
                    .unwrap()
                })
            })
        });
    }
    let cameras = 8;
    let frames = vec![
        CameraFrames {
            previous: pv,
            current: cv,
            weights: Some([kv, kv]),
        };
        cameras
    ];
    // Each camera's rows: the points in another order, three in four not seeded.
    let (mut last, mut earlier) = (Vec::new(), Vec::new());
    for k in 0..cameras {
        for p in 0..n {
            let q = (p * 7 + k * 131) % n;
            let seeded = (p + k) % 4 == 0;
            last.push(if seeded { points[q] } else { [f64::NAN; 2] });
            earlier.push(before[q]);
        }
    }
    let options = TrackOptions {
        matching: MatchOptions {
            size: 15,
            max_iterations: 8,
            max_shift: 7.0,
            ..TrackOptions::default().matching
        },
        radius: 6,
        min_correlation: 0.5,
        forward_backward: 0.6,
        weighted_box: false,
    };
    let m = cameras * n;
    let (mut positions, mut flags) = (vec![[0.0; 2]; m], vec![0u8; m]);
    let (mut covariance, mut correlation) = (vec![[0.0; 4]; m], vec![0.0; m]);
    let two = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap();
    group.bench_function("step_8_cameras_2_threads", |b| {
        b.iter(|| {
            two.install(|| {
                track_cameras(
                    &frames,
                    black_box(&last),
                    &earlier,
                    &options,
                    CameraStep {
                        positions: &mut positions,
                        flags: &mut flags,
                        covariance: &mut covariance,
                        correlation: &mut correlation,
                    },
                )
                .unwrap()
            })
        })
    });
    group.finish();
}

criterion_group!(benches, track);
criterion_main!(benches);
