//! The tracker's spatial matches of one frame: 8 cameras of 640x480 (the same procedural
//! texture under each camera's own affine map, gain 1.1, noise 2), every one of the 56
//! ordered camera pairs with 30 patches of 11x11 started 1.5 px off (1,680 patches, as
//! re-tie and re-acquisition ask ~80-100 pairs of a few dozen patches a frame). Per pair:
//! one `match_staged_patches` call per pair, as the tracker called it; batched: one
//! `match_pair_patches` call. One thread and all threads. Same patches, same results
//! (bit-identical: `rust/lsm/pairs_tests.rs`).

use criterion::{criterion_group, criterion_main, Criterion};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

use _core::lsm::{
    match_pair_patches, match_staged_patches, ImageView, MatchOptions, MatchOutput, Stage,
};

const WIDTH: usize = 640;
const HEIGHT: usize = 480;
const CAMERAS: usize = 8;
const PER_PAIR: usize = 30;

fn texture(rng: &mut ChaCha8Rng) -> impl Fn(f64, f64) -> f64 {
    let waves: Vec<([f64; 2], f64)> = (0..30)
        .map(|_| {
            let angle = rng.random_range(0.0..std::f64::consts::TAU);
            let frequency = rng.random_range(0.2..1.0);
            (
                [frequency * angle.cos(), frequency * angle.sin()],
                rng.random_range(0.0..std::f64::consts::TAU),
            )
        })
        .collect();
    let amplitude = 35.0 * (2.0f64 / 30.0).sqrt();
    move |u, v| {
        128.0
            + amplitude
                * waves
                    .iter()
                    .map(|(w, phase)| (w[0] * u + w[1] * v + phase).sin())
                    .sum::<f64>()
    }
}

fn noise(rng: &mut ChaCha8Rng) -> f64 {
    let (a, b): (f64, f64) = (rng.random_range(1e-12..1.0), rng.random_range(0.0..1.0));
    2.0 * (-2.0 * a.ln()).sqrt() * (std::f64::consts::TAU * b).cos()
}

/// Camera image: the texture at `x` shown at pixel `y = M x + t`.
fn render(
    f: &impl Fn(f64, f64) -> f64,
    m: [f64; 4],
    t: [f64; 2],
    rng: &mut ChaCha8Rng,
) -> Vec<f32> {
    let det = m[0] * m[3] - m[1] * m[2];
    let inv = [m[3] / det, -m[1] / det, -m[2] / det, m[0] / det];
    (0..WIDTH * HEIGHT)
        .map(|i| {
            let (u, v) = ((i % WIDTH) as f64 - t[0], (i / WIDTH) as f64 - t[1]);
            let x = [inv[0] * u + inv[1] * v, inv[2] * u + inv[3] * v];
            (1.1 * f(x[0], x[1]) + 5.0 + noise(rng)) as f32
        })
        .collect()
}

struct Buffers {
    status: Vec<u8>,
    affine: Vec<[f64; 6]>,
    radiometry: Vec<[f64; 2]>,
    sigma0: Vec<f64>,
    correlation: Vec<f64>,
    iterations: Vec<u32>,
    covariance: Vec<f64>,
    stages: Vec<Stage>,
}

impl Buffers {
    fn new(n: usize) -> Self {
        Self {
            status: vec![0; n],
            affine: vec![[0.0; 6]; n],
            radiometry: vec![[0.0; 2]; n],
            sigma0: vec![0.0; n],
            correlation: vec![0.0; n],
            iterations: vec![0; n],
            covariance: vec![0.0; n * 64],
            stages: vec![Stage::NONE; n],
        }
    }

    /// Outputs of patches `a..b`.
    fn out(&mut self, a: usize, b: usize) -> (MatchOutput<'_>, &mut [Stage]) {
        (
            MatchOutput {
                status: &mut self.status[a..b],
                affine: &mut self.affine[a..b],
                radiometry: &mut self.radiometry[a..b],
                sigma0: &mut self.sigma0[a..b],
                correlation: &mut self.correlation[a..b],
                iterations: &mut self.iterations[a..b],
                covariance: &mut self.covariance[a * 64..b * 64],
            },
            &mut self.stages[a..b],
        )
    }
}

fn lsm_pairs(c: &mut Criterion) {
    let mut rng = ChaCha8Rng::seed_from_u64(15);
    let f = texture(&mut rng);
    let maps: Vec<([f64; 4], [f64; 2])> = (0..CAMERAS)
        .map(|_| {
            (
                [
                    rng.random_range(0.93..1.07),
                    rng.random_range(-0.08..0.08),
                    rng.random_range(-0.08..0.08),
                    rng.random_range(0.93..1.07),
                ],
                [rng.random_range(-6.0..6.0), rng.random_range(-6.0..6.0)],
            )
        })
        .collect();
    let images: Vec<Vec<f32>> = maps
        .iter()
        .map(|&(m, t)| render(&f, m, t, &mut rng))
        .collect();
    let views: Vec<ImageView<'_>> = images
        .iter()
        .map(|data| ImageView {
            data,
            width: WIDTH,
            height: HEIGHT,
        })
        .collect();
    let optional: Vec<Option<ImageView<'_>>> = views.iter().copied().map(Some).collect();
    let apply = |(m, t): ([f64; 4], [f64; 2]), x: [f64; 2]| {
        [
            m[0] * x[0] + m[1] * x[1] + t[0],
            m[2] * x[0] + m[3] * x[1] + t[1],
        ]
    };
    // Patches grouped by pair, in the tracker's order (reference, then target).
    let mut pairs = Vec::new();
    let mut points = Vec::new();
    let mut starts = Vec::new();
    let mut groups = Vec::new();
    for r in 0..CAMERAS {
        for k in (0..CAMERAS).filter(|&k| k != r) {
            let first = points.len();
            for _ in 0..PER_PAIR {
                let x = [rng.random_range(60.0..580.0), rng.random_range(60.0..420.0)];
                let p = apply(maps[r], x);
                let q = apply(maps[k], x);
                pairs.push([r, k]);
                points.push(p);
                starts.push([1.0, 0.0, q[0] + 1.5, 0.0, 1.0, q[1] - 1.2]);
            }
            groups.push((r, k, first, points.len()));
        }
    }
    let n = points.len();
    let options = MatchOptions::default();
    let mut buffers = Buffers::new(n);
    let mut group = c.benchmark_group("lsm_pairs_56x30_patches_11x11_8cams");
    group.sample_size(10);
    for threads in [1usize, 0] {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        let suffix = if threads == 1 {
            "1_thread"
        } else {
            "all_threads"
        };
        group.bench_function(format!("per_pair_{suffix}"), |b| {
            b.iter(|| {
                pool.install(|| {
                    for &(r, k, a, e) in &groups {
                        let (out, stages) = buffers.out(a, e);
                        match_staged_patches(
                            &views[r],
                            None,
                            black_box(&points[a..e]),
                            std::slice::from_ref(&views[k]),
                            &starts[a..e],
                            None,
                            &options,
                            out,
                            stages,
                        )
                        .unwrap();
                    }
                })
            })
        });
        group.bench_function(format!("batched_{suffix}"), |b| {
            b.iter(|| {
                pool.install(|| {
                    let (out, stages) = buffers.out(0, n);
                    match_pair_patches(
                        &optional,
                        None,
                        &pairs,
                        black_box(&points),
                        &starts,
                        &options,
                        out,
                        stages,
                    )
                    .unwrap()
                })
            })
        });
    }
    group.finish();
}

criterion_group!(benches, lsm_pairs);
criterion_main!(benches);
