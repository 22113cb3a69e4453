//! The frame step in one pass over every camera's views against the staged passes it
//! replaced (one pass per stage and camera, through the matcher's batches), to the bit.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::flags::Flag;
use super::ncc::{box_search, BoxScratch};
use super::step::{track_cameras, CameraFrames, CameraStep, TrackOptions};
use crate::error::Error;
use crate::lsm::{
    match_weighted_patches, ImageView, Interpolation, MatchOptions, MatchOutput, Status, PARAMETERS,
};

/// A random smooth texture (sum of sines) shifted by `shift`, with noise.
fn texture(width: usize, height: usize, shift: [f64; 2], seed: u64) -> Vec<f32> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let waves: Vec<[f64; 4]> = (0..12)
        .map(|_| {
            let angle = rng.random_range(0.0..std::f64::consts::TAU);
            let f = rng.random_range(0.15..0.7);
            [
                f * angle.cos(),
                f * angle.sin(),
                rng.random_range(0.0..6.3),
                12.0,
            ]
        })
        .collect();
    (0..width * height)
        .map(|i| {
            let (x, y) = ((i % width) as f64 - shift[0], (i / width) as f64 - shift[1]);
            let g: f64 = waves
                .iter()
                .map(|w| w[3] * (w[0] * x + w[1] * y + w[2]).sin())
                .sum();
            (128.0 + g + rng.random_range(-1.5..1.5)) as f32
        })
        .collect()
}

/// A camera's positions, flags, covariances and correlations.
type Outputs = (Vec<[f64; 2]>, Vec<u8>, Vec<[f64; 4]>, Vec<f64>);

/// One camera's step as the staged passes ran it: the box searches, then the forward
/// matches of the views that passed as one batch, then the backward matches as another.
fn staged(
    frames: &CameraFrames<'_>,
    last: &[[f64; 2]],
    before: &[[f64; 2]],
    options: &TrackOptions,
) -> Outputs {
    let n = last.len();
    let (mut positions, mut flags) = (vec![[f64::NAN; 2]; n], vec![0u8; n]);
    let (mut covariance, mut correlation) = (vec![[f64::NAN; 4]; n], vec![f64::NAN; n]);
    let weights = frames.weights.as_ref();
    let box_weights = weights.filter(|_| options.weighted_box).map(|w| &w[0]);
    let mut scratch = BoxScratch::default();
    let mut active = Vec::new();
    let mut centres = Vec::new();
    for p in 0..n {
        let x = last[p];
        if !(x[0].is_finite() && x[1].is_finite()) {
            flags[p] = Flag::NotSeeded as u8;
            continue;
        }
        let b = before[p];
        let prediction = if b[0].is_finite() && b[1].is_finite() {
            [2.0 * x[0] - b[0], 2.0 * x[1] - b[1]]
        } else {
            x
        };
        let size = options.matching.size;
        let (previous, current) = (&frames.previous, &frames.current);
        flags[p] = match box_search(
            previous,
            x,
            current,
            prediction,
            size,
            options.radius,
            box_weights,
            &mut scratch,
        ) {
            None => Flag::ImageBorder as u8,
            Some(best) if !(best.score >= options.min_correlation) => Flag::LowCorrelation as u8,
            Some(best) => {
                active.push(p);
                centres.push(best.centre);
                Flag::Tracked as u8
            }
        };
    }
    let points: Vec<_> = active.iter().map(|&p| last[p]).collect();
    let starts: Vec<_> = centres
        .iter()
        .map(|c| [1.0, 0.0, c[0], 0.0, 1.0, c[1]])
        .collect();
    let forward = batch(
        &frames.previous,
        weights.map(|w| &w[0]),
        &points,
        &frames.current,
        &starts,
        &options.matching,
    );
    let (mut back_points, mut back_starts, mut back_of) = (Vec::new(), Vec::new(), Vec::new());
    for (k, &p) in active.iter().enumerate() {
        let status = forward.0[k];
        flags[p] = if status == Status::LeftImage as u8 {
            Flag::ImageBorder as u8
        } else if status != Status::Converged as u8 && status != Status::MaxIterations as u8 {
            Flag::MatchFailed as u8
        } else if !(forward.2[k] >= options.min_correlation) {
            Flag::LowCorrelation as u8
        } else {
            let m = forward.1[k];
            let det = m[0] * m[4] - m[1] * m[3];
            back_points.push([m[2], m[5]]);
            back_starts.push([
                m[4] / det,
                -m[1] / det,
                last[p][0],
                -m[3] / det,
                m[0] / det,
                last[p][1],
            ]);
            back_of.push(k);
            Flag::Tracked as u8
        };
    }
    let check = MatchOptions {
        max_iterations: options.matching.max_iterations.min(5),
        interpolation: Interpolation::Bilinear,
        sandwich: false,
        ..options.matching
    };
    let backward = batch(
        &frames.current,
        weights.map(|w| &w[1]),
        &back_points,
        &frames.previous,
        &back_starts,
        &check,
    );
    for (j, &k) in back_of.iter().enumerate() {
        let p = active[k];
        let m = backward.1[j];
        let miss = (m[2] - last[p][0]).hypot(m[5] - last[p][1]);
        let estimate = backward.0[j] == Status::Converged as u8
            || backward.0[j] == Status::MaxIterations as u8;
        if !estimate || !(miss <= options.forward_backward) {
            flags[p] = Flag::ForwardBackward as u8;
            continue;
        }
        let f = forward.1[k];
        positions[p] = [f[2], f[5]];
        let c = &forward.3[k * PARAMETERS * PARAMETERS..];
        covariance[p] = [c[0], c[1], c[PARAMETERS], c[PARAMETERS + 1]];
        correlation[p] = forward.2[k];
    }
    (positions, flags, covariance, correlation)
}

/// One batch of matches: status, affine, correlation, covariance.
fn batch(
    template: &ImageView<'_>,
    weights: Option<&ImageView<'_>>,
    points: &[[f64; 2]],
    search: &ImageView<'_>,
    starts: &[[f64; 6]],
    options: &MatchOptions,
) -> (Vec<u8>, Vec<[f64; 6]>, Vec<f64>, Vec<f64>) {
    let m = points.len();
    let (mut status, mut affine, mut correlation) = (vec![0; m], vec![[0.0; 6]; m], vec![0.0; m]);
    let mut covariance = vec![0.0; m * PARAMETERS * PARAMETERS];
    let (mut radiometry, mut sigma0, mut iterations) =
        (vec![[0.0; 2]; m], vec![0.0; m], vec![0; m]);
    if m > 0 {
        match_weighted_patches(
            template,
            weights,
            points,
            std::slice::from_ref(search),
            starts,
            None,
            options,
            MatchOutput {
                status: &mut status,
                affine: &mut affine,
                radiometry: &mut radiometry,
                sigma0: &mut sigma0,
                correlation: &mut correlation,
                iterations: &mut iterations,
                covariance: &mut covariance,
            },
        )
        .unwrap();
    }
    (status, affine, correlation, covariance)
}

fn same<const D: usize>(a: &[[f64; D]], b: &[[f64; D]]) -> bool {
    a.iter()
        .flatten()
        .zip(b.iter().flatten())
        .all(|(x, y)| x.to_bits() == y.to_bits())
}

/// Three cameras of different sizes and motions; views inside, near the border and
/// unseeded, predictions right, absent and wrong; masks with a cut.
#[test]
fn one_pass_over_every_camera_equals_the_staged_passes_to_the_bit() {
    let sizes = [(160usize, 120usize), (140, 150), (200, 90)];
    let shifts = [[2.3, -1.4], [-3.1, 0.6], [0.4, 2.8]];
    let n = 120;
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let images: Vec<_> = sizes
        .iter()
        .zip(shifts)
        .enumerate()
        .map(|(k, (&(w, h), s))| {
            (
                texture(w, h, [0.0; 2], k as u64),
                texture(w, h, s, k as u64),
            )
        })
        .collect();
    let masks: Vec<_> = sizes
        .iter()
        .map(|&(w, h)| {
            let cut = |i: usize| {
                if (i % w) % 37 < 4 || (i / w) % 41 < 3 {
                    0.0
                } else {
                    1.0
                }
            };
            (
                (0..w * h).map(cut).collect::<Vec<f32>>(),
                (0..w * h).map(|i| cut(i + 1)).collect::<Vec<f32>>(),
            )
        })
        .collect();
    let (mut last, mut before) = (Vec::new(), Vec::new());
    for (&(w, h), s) in sizes.iter().zip(shifts) {
        for p in 0..n {
            let x = [
                rng.random_range(-4.0..w as f64 + 4.0),
                rng.random_range(-4.0..h as f64 + 4.0),
            ];
            let x = if p % 17 == 0 { [f64::NAN; 2] } else { x };
            last.push(x);
            before.push(match p % 3 {
                0 => [x[0] - s[0], x[1] - s[1]],
                1 => [f64::NAN; 2],
                _ => [x[0] + 6.0, x[1] - 5.0],
            });
        }
    }
    let view = |data: &'static [f32], k: usize| ImageView {
        data,
        width: sizes[k].0,
        height: sizes[k].1,
    };
    let leak = |v: &Vec<f32>| -> &'static [f32] { Box::leak(v.clone().into_boxed_slice()) };
    for (weighted, weighted_box) in [(false, false), (true, false), (true, true)] {
        let cameras: Vec<CameraFrames<'_>> = (0..3)
            .map(|k| CameraFrames {
                previous: view(leak(&images[k].0), k),
                current: view(leak(&images[k].1), k),
                weights: weighted.then(|| [view(leak(&masks[k].0), k), view(leak(&masks[k].1), k)]),
            })
            .collect();
        let options = TrackOptions {
            matching: MatchOptions {
                size: 15,
                max_iterations: 8,
                max_shift: 7.0,
                interpolation: Interpolation::Bilinear,
                ..MatchOptions::default()
            },
            radius: 6,
            min_correlation: 0.5,
            forward_backward: 0.6,
            weighted_box,
        };
        let m = 3 * n;
        let (mut positions, mut flags) = (vec![[0.0; 2]; m], vec![0u8; m]);
        let (mut covariance, mut correlation) = (vec![[0.0; 4]; m], vec![0.0; m]);
        track_cameras(
            &cameras,
            &last,
            &before,
            &options,
            CameraStep {
                positions: &mut positions,
                flags: &mut flags,
                covariance: &mut covariance,
                correlation: &mut correlation,
            },
        )
        .unwrap();
        for (k, frames) in cameras.iter().enumerate() {
            let r = k * n..(k + 1) * n;
            let (p, f, c, r2) = staged(frames, &last[r.clone()], &before[r.clone()], &options);
            assert_eq!(flags[r.clone()], f[..], "camera {k}");
            assert!(same(&positions[r.clone()], &p), "camera {k}");
            assert!(same(&covariance[r.clone()], &c), "camera {k}");
            let corr: Vec<[f64; 1]> = r2.iter().map(|&x| [x]).collect();
            let got: Vec<[f64; 1]> = correlation[r].iter().map(|&x| [x]).collect();
            assert!(same(&got, &corr), "camera {k}");
        }
        // The scenes hold tracked views and every early failure.
        for flag in [
            Flag::Tracked,
            Flag::NotSeeded,
            Flag::ImageBorder,
            Flag::LowCorrelation,
        ] {
            assert!(
                flags.contains(&(flag as u8)),
                "{flag:?} ({weighted}, {weighted_box})"
            );
        }
        assert!(
            flags.iter().filter(|&&f| f == 0).count() > m / 5,
            "{flags:?}"
        );
    }
}

#[test]
fn views_not_a_whole_number_per_camera_are_refused() {
    let data = vec![0.0f32; 400];
    let image = ImageView {
        data: &data,
        width: 20,
        height: 20,
    };
    let frames = CameraFrames {
        previous: image,
        current: image,
        weights: None,
    };
    let (mut positions, mut flags) = (vec![[0.0; 2]; 3], vec![0u8; 3]);
    let (mut covariance, mut correlation) = (vec![[0.0; 4]; 3], vec![0.0; 3]);
    let got = track_cameras(
        &[frames, frames],
        &[[1.0; 2]; 3],
        &[[1.0; 2]; 3],
        &TrackOptions::default(),
        CameraStep {
            positions: &mut positions,
            flags: &mut flags,
            covariance: &mut covariance,
            correlation: &mut correlation,
        },
    );
    assert!(
        matches!(
            got,
            Err(Error::LengthMismatch {
                argument: "last",
                ..
            })
        ),
        "{got:?}"
    );
    // No camera, no views: nothing to do.
    let none = CameraStep {
        positions: &mut [],
        flags: &mut [],
        covariance: &mut [],
        correlation: &mut [],
    };
    assert!(track_cameras(&[], &[], &[], &TrackOptions::default(), none).is_ok());
}
