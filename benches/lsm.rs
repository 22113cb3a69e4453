//! Least-squares matching of 11x11 patches: 2,000 points of a 640x480 procedural texture
//! (wavelengths 6 to 30 px, contrast 35 grey levels, noise 2) into one affinely warped
//! search image (and into three), starts 2 px off; one thread and all threads, bilinear and
//! bicubic resampling.

use criterion::{criterion_group, criterion_main, Criterion};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

use _core::lsm::{match_patches, ImageView, Interpolation, MatchOptions, MatchOutput};

const WIDTH: usize = 640;
const HEIGHT: usize = 480;

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

/// Search image `s`: the texture under `y = M x + t`, gain 1.1, offset 5.
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

fn view(data: &[f32]) -> ImageView<'_> {
    ImageView {
        data,
        width: WIDTH,
        height: HEIGHT,
    }
}

fn lsm(c: &mut Criterion) {
    let mut rng = ChaCha8Rng::seed_from_u64(14);
    let f = texture(&mut rng);
    let template = render(&f, [1.0, 0.0, 0.0, 1.0], [0.0, 0.0], &mut rng);
    let warps = [
        ([1.05, 0.1, -0.05, 0.97], [3.3, -2.7]),
        ([0.95, -0.1, 0.08, 1.02], [-4.1, 2.2]),
        ([1.0, 0.05, 0.0, 1.1], [1.6, -3.9]),
    ];
    let searches: Vec<Vec<f32>> = warps
        .iter()
        .map(|&(m, t)| render(&f, m, t, &mut rng))
        .collect();
    let n = 2000;
    let points: Vec<[f64; 2]> = (0..n)
        .map(|_| {
            [
                rng.random_range(40.0..600.0f64).round(),
                rng.random_range(40.0..440.0f64).round(),
            ]
        })
        .collect();
    let template_view = view(&template);
    let search_views: Vec<ImageView> = searches.iter().map(|s| view(s)).collect();
    let mut group = c.benchmark_group("lsm_2000_patches_11x11");
    group.sample_size(10);
    for images in [1usize, 3] {
        let starts: Vec<[f64; 6]> = points
            .iter()
            .flat_map(|p| {
                warps[..images].iter().map(|&(m, t)| {
                    let c = [
                        m[0] * p[0] + m[1] * p[1] + t[0],
                        m[2] * p[0] + m[3] * p[1] + t[1],
                    ];
                    [1.0, 0.0, c[0] + 1.5, 0.0, 1.0, c[1] - 1.2]
                })
            })
            .collect();
        let pairs = n * images;
        let mut status = vec![0u8; pairs];
        let mut affine = vec![[0.0; 6]; pairs];
        let mut radiometry = vec![[0.0; 2]; pairs];
        let mut sigma0 = vec![0.0; pairs];
        let mut correlation = vec![0.0; pairs];
        let mut iterations = vec![0u32; pairs];
        let mut covariance = vec![0.0; n * 64 * images * images];
        for interpolation in [Interpolation::Bilinear, Interpolation::Bicubic] {
            let options = MatchOptions {
                interpolation,
                ..Default::default()
            };
            for threads in [1usize, 0] {
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                let label = format!(
                    "{images}_image{}_{:?}_{}",
                    if images > 1 { "s" } else { "" },
                    interpolation,
                    if threads == 1 {
                        "1_thread".to_string()
                    } else {
                        "all_threads".to_string()
                    }
                )
                .to_lowercase();
                group.bench_function(label, |b| {
                    b.iter(|| {
                        pool.install(|| {
                            match_patches(
                                &template_view,
                                black_box(&points),
                                &search_views[..images],
                                &starts,
                                None,
                                &options,
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
                            .unwrap()
                        })
                    })
                });
            }
        }
    }
    group.finish();
}

criterion_group!(benches, lsm);
criterion_main!(benches);
