//! The batched camera-pair match against the per-pair calls it replaces: the same patches
//! give the same bits, whatever the order, the grouping, the shared templates or the
//! threads.

use super::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Per-patch results as bits (NaN compared as bits too).
#[derive(Debug, PartialEq, Eq, Clone)]
struct Bits {
    status: u8,
    affine: [u64; 6],
    radiometry: [u64; 2],
    sigma0: u64,
    correlation: u64,
    iterations: u32,
    covariance: Vec<u64>,
}

struct Outputs {
    status: Vec<u8>,
    affine: Vec<[f64; 6]>,
    radiometry: Vec<[f64; 2]>,
    sigma0: Vec<f64>,
    correlation: Vec<f64>,
    iterations: Vec<u32>,
    covariance: Vec<f64>,
}

impl Outputs {
    fn new(n: usize) -> Self {
        Self {
            status: vec![0; n],
            affine: vec![[0.0; 6]; n],
            radiometry: vec![[0.0; 2]; n],
            sigma0: vec![0.0; n],
            correlation: vec![0.0; n],
            iterations: vec![0; n],
            covariance: vec![0.0; n * 64],
        }
    }

    fn out(&mut self) -> MatchOutput<'_> {
        MatchOutput {
            status: &mut self.status,
            affine: &mut self.affine,
            radiometry: &mut self.radiometry,
            sigma0: &mut self.sigma0,
            correlation: &mut self.correlation,
            iterations: &mut self.iterations,
            covariance: &mut self.covariance,
        }
    }

    fn bits(&self, i: usize) -> Bits {
        Bits {
            status: self.status[i],
            affine: self.affine[i].map(f64::to_bits),
            radiometry: self.radiometry[i].map(f64::to_bits),
            sigma0: self.sigma0[i].to_bits(),
            correlation: self.correlation[i].to_bits(),
            iterations: self.iterations[i],
            covariance: self.covariance[i * 64..(i + 1) * 64]
                .iter()
                .map(|x| x.to_bits())
                .collect(),
        }
    }
}

/// A textured scene seen by `cameras` images: each camera's image is the same band-limited
/// texture under its own small affine map, gain, offset and noise, so that matches across
/// pairs converge, and some (far starts, flat corners, edges) fail with their statuses.
fn images(rng: &mut ChaCha8Rng, cameras: usize, width: usize, height: usize) -> Vec<Vec<f32>> {
    let waves: Vec<([f64; 2], f64, f64)> = (0..10)
        .map(|_| {
            let angle = rng.random_range(0.0..std::f64::consts::TAU);
            let frequency = rng.random_range(0.2..0.7);
            (
                [frequency * angle.cos(), frequency * angle.sin()],
                rng.random_range(0.0..std::f64::consts::TAU),
                rng.random_range(4.0..14.0),
            )
        })
        .collect();
    (0..cameras)
        .map(|_| {
            let m = [
                rng.random_range(0.9..1.1),
                rng.random_range(-0.1..0.1),
                rng.random_range(-0.1..0.1),
                rng.random_range(0.9..1.1),
            ];
            let b = [rng.random_range(-3.0..3.0), rng.random_range(-3.0..3.0)];
            let gain = rng.random_range(0.8..1.2);
            let mut data = vec![0.0f32; width * height];
            for r in 0..height {
                for c in 0..width {
                    let (u, v) = (c as f64, r as f64);
                    // A flat band on the right: low-texture patches.
                    let x = [m[0] * u + m[1] * v + b[0], m[2] * u + m[3] * v + b[1]];
                    let texture: f64 = if c + 12 >= width {
                        0.0
                    } else {
                        waves
                            .iter()
                            .map(|(w, phase, a)| a * (w[0] * x[0] + w[1] * x[1] + phase).sin())
                            .sum()
                    };
                    data[r * width + c] =
                        (128.0 + gain * texture + rng.random_range(-1.0..1.0)) as f32;
                }
            }
            data
        })
        .collect()
}

fn view(data: &[f32], width: usize, height: usize) -> ImageView<'_> {
    ImageView {
        data,
        width,
        height,
    }
}

#[test]
fn batched_pairs_equal_the_per_pair_calls_to_the_bit() {
    let mut rng = ChaCha8Rng::seed_from_u64(15);
    let (width, height, cameras) = (80, 64, 4);
    let data = images(&mut rng, cameras, width, height);
    // Weights on cameras 0 and 2 (a soft disc and a half-plane), none on 1 and 3.
    let weight_data: Vec<Option<Vec<f32>>> = (0..cameras)
        .map(|c| {
            (c % 2 == 0).then(|| {
                (0..width * height)
                    .map(|i| {
                        let (u, v) = ((i % width) as f64, (i / width) as f64);
                        let w = if c == 0 {
                            1.0 - ((u - 40.0).hypot(v - 32.0) / 40.0).min(1.0)
                        } else {
                            f64::from(u < 50.0)
                        };
                        w as f32
                    })
                    .collect()
            })
        })
        .collect();
    let views: Vec<Option<ImageView<'_>>> =
        data.iter().map(|d| Some(view(d, width, height))).collect();
    let weights: Vec<Option<ImageView<'_>>> = weight_data
        .iter()
        .map(|w| w.as_ref().map(|d| view(d, width, height)))
        .collect();
    let n = 300;
    let mut pairs: Vec<[usize; 2]> = Vec::with_capacity(n);
    let mut points: Vec<[f64; 2]> = Vec::with_capacity(n);
    let mut starts = Vec::with_capacity(n);
    for i in 0..n {
        let mut r = rng.random_range(0..cameras);
        // Some points near or beyond the border (LeftImage), most inside.
        let mut p = [
            rng.random_range(-2.0..width as f64 + 2.0),
            rng.random_range(-2.0..height as f64 + 2.0),
        ];
        // Two in five patches match an earlier patch's point from the same reference
        // camera (into any target, its own too): the batch shares their template. The
        // shared points fall anywhere in the input, as the tracker's do.
        if i > 0 && rng.random_bool(0.4) {
            let j = rng.random_range(0..i);
            (r, p) = (pairs[j][0], points[j]);
        }
        let k = (r + rng.random_range(1..cameras)) % cameras;
        let spread = if rng.random_bool(0.2) { 6.0 } else { 2.0 };
        let a = [
            rng.random_range(0.85..1.15),
            rng.random_range(-0.15..0.15),
            p[0] + rng.random_range(-spread..spread),
            rng.random_range(-0.15..0.15),
            rng.random_range(0.85..1.15),
            p[1] + rng.random_range(-spread..spread),
        ];
        pairs.push([r, k]);
        points.push(p);
        starts.push(a);
    }
    for size in [7, 11] {
        let options = MatchOptions {
            size,
            max_iterations: 20,
            max_shift: size as f64 / 2.0,
            min_texture: 0.5,
            ..Default::default()
        };
        for with_weights in [false, true] {
            let w = with_weights.then_some(weights.as_slice());
            // Per pair, as the tracker called it: one call per (reference, target) with the
            // pair's patches in order.
            let mut expected = vec![None; n];
            for r in 0..cameras {
                for k in 0..cameras {
                    let rows: Vec<usize> = (0..n).filter(|&i| pairs[i] == [r, k]).collect();
                    if rows.is_empty() {
                        continue;
                    }
                    let pts: Vec<[f64; 2]> = rows.iter().map(|&i| points[i]).collect();
                    let st: Vec<[f64; 6]> = rows.iter().map(|&i| starts[i]).collect();
                    let mut o = Outputs::new(rows.len());
                    let mut stages = vec![Stage::NONE; rows.len()];
                    match_staged_patches(
                        views[r].as_ref().unwrap(),
                        w.and_then(|w| w[r].as_ref()),
                        &pts,
                        std::slice::from_ref(views[k].as_ref().unwrap()),
                        &st,
                        None,
                        &options,
                        o.out(),
                        &mut stages,
                    )
                    .unwrap();
                    for (j, &i) in rows.iter().enumerate() {
                        expected[i] = Some(o.bits(j));
                    }
                }
            }
            let shared = (0..n)
                .filter(|&i| (0..i).any(|j| pairs[j][0] == pairs[i][0] && points[j] == points[i]))
                .count();
            assert!(shared > n / 4, "only {shared} patches share a template");
            let statuses: std::collections::BTreeSet<u8> = expected
                .iter()
                .map(|b| b.as_ref().unwrap().status)
                .collect();
            // The case covers converged and failed matches alike.
            assert!(
                statuses.len() >= 3 && statuses.contains(&(Status::Converged as u8)),
                "statuses {statuses:?}"
            );
            for threads in [1, 3] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let mut o = Outputs::new(n);
                let mut stages = vec![Stage::NONE; n];
                pool.install(|| {
                    match_pair_patches(
                        &views,
                        w,
                        &pairs,
                        &points,
                        &starts,
                        &options,
                        o.out(),
                        &mut stages,
                    )
                })
                .unwrap();
                for (i, want) in expected.iter().enumerate() {
                    assert_eq!(
                        &o.bits(i),
                        want.as_ref().unwrap(),
                        "patch {i} pair {:?} size {size} weights {with_weights} threads {threads}",
                        pairs[i]
                    );
                }
            }
        }
    }
}

#[test]
fn batched_pairs_reject_bad_cameras_and_shapes() {
    let (width, height) = (16, 16);
    let data = vec![100.0f32; width * height];
    let views = vec![Some(view(&data, width, height)), None];
    let options = MatchOptions::default();
    let start = [1.0, 0.0, 8.0, 0.0, 1.0, 8.0];
    let run =
        |pairs: &[[usize; 2]], starts: &[[f64; 6]], weights: Option<&[Option<ImageView<'_>>]>| {
            let mut o = Outputs::new(1);
            let mut stages = vec![Stage::NONE; 1];
            match_pair_patches(
                &views,
                weights,
                pairs,
                &[[8.0, 8.0]],
                starts,
                &options,
                o.out(),
                &mut stages,
            )
        };
    // Camera beyond the images, or an image not given.
    assert!(matches!(
        run(&[[0, 2]], &[start], None),
        Err(Error::IndexOutOfRange {
            argument: "cameras",
            row: 0,
            value: 2,
            bound: 2
        })
    ));
    assert!(matches!(
        run(&[[1, 0]], &[start], None),
        Err(Error::InvalidOption {
            argument: "cameras",
            ..
        })
    ));
    // A start map that flips the patch.
    let flipped = [-1.0, 0.0, 8.0, 0.0, 1.0, 8.0];
    assert!(matches!(
        run(&[[0, 0]], &[flipped], None),
        Err(Error::InvalidOption {
            argument: "initial",
            ..
        })
    ));
    // Weights for fewer cameras than images, and weights of another size than the image.
    let small = vec![1.0f32; 4];
    let wrong = [Some(view(&small, 2, 2)), None];
    assert!(matches!(
        run(&[[0, 0]], &[start], Some(&wrong[..1])),
        Err(Error::LengthMismatch {
            argument: "weights",
            ..
        })
    ));
    assert!(matches!(
        run(&[[0, 0]], &[start], Some(&wrong)),
        Err(Error::WrongLength {
            argument: "weights",
            ..
        })
    ));
    // A flat patch is no error: it gets its status.
    assert!(run(&[[0, 0]], &[start], None).is_ok());
}
