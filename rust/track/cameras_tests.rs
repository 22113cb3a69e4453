//! Tests of the step of every camera at once ([`super::track_cameras`]): each camera's
//! points come out as from their own camera's call, to the bit, whatever the grouping and
//! the thread count.

use super::*;
use crate::lsm::{ImageView, MatchOptions};

/// A smooth texture of `width x height` (sum of sines with a per-camera phase), shifted by
/// `shift` pixels.
fn texture(width: usize, height: usize, phase: f64, shift: [f64; 2]) -> Vec<f32> {
    let waves = [
        (0.31, 0.17, 40.0),
        (-0.23, 0.29, 35.0),
        (0.11, -0.41, 25.0),
        (0.47, 0.07, 20.0),
    ];
    let mut data = Vec::with_capacity(width * height);
    for v in 0..height {
        for u in 0..width {
            let (x, y) = (u as f64 - shift[0], v as f64 - shift[1]);
            let g: f64 = waves
                .iter()
                .enumerate()
                .map(|(i, &(a, b, amp))| amp * (a * x + b * y + phase * (i + 1) as f64).sin())
                .sum();
            data.push((128.0 + g) as f32);
        }
    }
    data
}

/// A mask of ones with a band of zeros every 23 columns (the weighted match and the
/// weighted box both see cut templates).
fn mask(width: usize, height: usize, offset: usize) -> Vec<f32> {
    (0..width * height)
        .map(|i| if (i % width + offset) % 23 < 4 { 0.0 } else { 1.0 })
        .collect()
}

/// One camera's scene: images, masks, points (some NaN, some at the border, some whose
/// prediction misses the box) and the positions a frame before.
struct Scene {
    size: (usize, usize),
    previous: Vec<f32>,
    current: Vec<f32>,
    masks: [Vec<f32>; 2],
    last: Vec<[f64; 2]>,
    before: Vec<[f64; 2]>,
}

fn scene(k: usize, n: usize) -> Scene {
    // Cameras of different sizes, textures and motions.
    let (w, h) = (110 + 17 * k, 90 + 11 * k);
    let shift = [1.7 - 0.9 * k as f64, -1.1 + 0.6 * k as f64];
    let previous = texture(w, h, 0.7 * k as f64, [0.0; 2]);
    let mut current = texture(w, h, 0.7 * k as f64, shift);
    // An occluder in the current frame: its points fail the correlation.
    for v in 10..30 {
        for u in 10..30 {
            current[v * w + u] = 255.0 - current[v * w + u];
        }
    }
    let mut last = Vec::with_capacity(n);
    let mut before = Vec::with_capacity(n);
    for p in 0..n {
        let x = [
            8.0 + ((p * 37 + 11 * k) % (w - 16)) as f64 + 0.25 * (p % 4) as f64,
            8.0 + ((p * 53 + 7 * k) % (h - 16)) as f64 + 0.5 * (p % 2) as f64,
        ];
        last.push(if p % 9 == 4 { [f64::NAN; 2] } else { x });
        before.push(match p % 3 {
            0 => [f64::NAN; 2],
            1 => [x[0] - shift[0], x[1] - shift[1]],
            _ => [x[0] + 9.0, x[1] - 9.0],
        });
    }
    Scene {
        size: (w, h),
        previous,
        current,
        masks: [mask(w, h, k), mask(w, h, k + 2)],
        last,
        before,
    }
}

fn view((w, h): (usize, usize), data: &[f32]) -> ImageView<'_> {
    ImageView {
        data,
        width: w,
        height: h,
    }
}

type Stepped = (Vec<[f64; 2]>, Vec<u8>, Vec<[f64; 4]>, Vec<f64>);

fn run(
    cameras: &[CameraImages<'_>],
    last: &[[f64; 2]],
    before: &[[f64; 2]],
    options: &TrackOptions,
) -> Stepped {
    let m = last.len();
    let (mut positions, mut flags) = (vec![[0.0; 2]; m], vec![0u8; m]);
    let (mut covariance, mut correlation) = (vec![[0.0; 4]; m], vec![0.0; m]);
    track_cameras(
        cameras,
        last,
        before,
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

fn bits(s: &Stepped) -> (Vec<[u64; 2]>, Vec<u8>, Vec<[u64; 4]>, Vec<u64>) {
    (
        s.0.iter().map(|p| p.map(f64::to_bits)).collect(),
        s.1.clone(),
        s.2.iter().map(|c| c.map(f64::to_bits)).collect(),
        s.3.iter().map(|r| r.to_bits()).collect(),
    )
}

#[test]
fn every_camera_at_once_equals_each_camera_alone_to_the_bit() {
    let n = 60;
    let scenes: Vec<Scene> = (0..3).map(|k| scene(k, n)).collect();
    let pool = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
    };
    for weighted in [false, true] {
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
            let cameras: Vec<CameraImages<'_>> = scenes
                .iter()
                .map(|s| CameraImages {
                    previous: view(s.size, &s.previous),
                    current: view(s.size, &s.current),
                    weights: weighted.then(|| [view(s.size, &s.masks[0]), view(s.size, &s.masks[1])]),
                })
                .collect();
            let last: Vec<[f64; 2]> = scenes.iter().flat_map(|s| s.last.clone()).collect();
            let before: Vec<[f64; 2]> = scenes.iter().flat_map(|s| s.before.clone()).collect();
            // Each camera alone, one thread.
            let alone: Vec<Stepped> = pool(1).install(|| {
                (0..3)
                    .map(|k| run(&cameras[k..k + 1], &scenes[k].last, &scenes[k].before, &options))
                    .collect()
            });
            let mut tracked = 0;
            for threads in [1, 3] {
                let all = pool(threads).install(|| run(&cameras, &last, &before, &options));
                for (k, one) in alone.iter().enumerate() {
                    let part = (
                        all.0[k * n..(k + 1) * n].to_vec(),
                        all.1[k * n..(k + 1) * n].to_vec(),
                        all.2[k * n..(k + 1) * n].to_vec(),
                        all.3[k * n..(k + 1) * n].to_vec(),
                    );
                    assert_eq!(bits(&part), bits(one), "camera {k}, {threads} threads");
                }
                tracked = all.1.iter().filter(|&&f| f == Flag::Tracked as u8).count();
            }
            // The scenes hold tracked points and every kind of failure.
            assert!(tracked > 3 * n / 3, "{tracked} tracked");
            let flags: Vec<u8> = alone.iter().flat_map(|s| s.1.clone()).collect();
            for flag in [Flag::NotSeeded, Flag::LowCorrelation, Flag::ImageBorder] {
                assert!(flags.contains(&(flag as u8)), "no {flag:?} in {flags:?}");
            }
        }
    }
}

#[test]
fn a_camera_count_that_does_not_divide_the_rows_is_refused() {
    let s = scene(0, 4);
    let camera = CameraImages {
        previous: view(s.size, &s.previous),
        current: view(s.size, &s.current),
        weights: None,
    };
    let last = vec![[20.0, 20.0]; 5];
    let m = last.len();
    let (mut positions, mut flags) = (vec![[0.0; 2]; m], vec![0u8; m]);
    let (mut covariance, mut correlation) = (vec![[0.0; 4]; m], vec![0.0; m]);
    let out = CameraStep {
        positions: &mut positions,
        flags: &mut flags,
        covariance: &mut covariance,
        correlation: &mut correlation,
    };
    let result = track_cameras(&[camera, camera], &last, &last, &TrackOptions::default(), out);
    assert!(matches!(result, Err(crate::Error::LengthMismatch { argument: "last", .. })));
}
