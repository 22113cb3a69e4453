//! One Levenberg-Marquardt iteration of the body fit at the size: 50,000 points and
//! 8 silhouettes of 2,000 rays each on a model with the default human's structure (16 parts,
//! 34 metaballs, 25 joint axes). An iteration is one linearisation (residuals, Jacobian,
//! normal blocks), one damped sparse Cholesky solve and one trial-cost evaluation.

use criterion::{criterion_group, criterion_main, Criterion};
use nalgebra::Vector3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::hint::black_box;

use _core::body::field::Field;
use _core::body::fit::{problem, FitOptions};
use _core::body::observe::Observations;
use _core::body::{Metaball, PartSpec, Skeleton};
use _core::lm::{ArrowNormal, ArrowProblem, ArrowSolver, LmOptions};

const I: [[f64; 3]; 3] = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];

fn rot_y(degrees: f64) -> [[f64; 3]; 3] {
    let (s, c) = degrees.to_radians().sin_cos();
    [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]]
}

/// The default human's tree: parent, offset, rest, axes, balls `(centre, skin semi-axes)`.
fn human() -> Skeleton {
    let x = [1.0, 0.0, 0.0];
    let y = [0.0, 1.0, 0.0];
    let z = [0.0, 0.0, 1.0];
    type Part = (
        Option<usize>,
        [f64; 3],
        [[f64; 3]; 3],
        Vec<[f64; 3]>,
        Vec<([f64; 3], [f64; 3])>,
    );
    let mut parts: Vec<Part> = vec![
        (
            None,
            [0.0; 3],
            I,
            vec![],
            vec![
                ([0.0, 0.0, 0.03], [0.15, 0.1, 0.09]),
                ([0.08, 0.0, -0.04], [0.09; 3]),
                ([-0.08, 0.0, -0.04], [0.09; 3]),
            ],
        ),
        (
            Some(0),
            [0.0, 0.0, 0.08],
            I,
            vec![x, y],
            vec![
                ([0.0, 0.0, 0.08], [0.13, 0.095, 0.1]),
                ([0.0, 0.01, 0.17], [0.135, 0.095, 0.08]),
            ],
        ),
        (
            Some(1),
            [0.0, 0.0, 0.2],
            I,
            vec![z],
            vec![
                ([0.0, 0.0, 0.08], [0.15, 0.1, 0.1]),
                ([0.09, 0.0, 0.2], [0.08, 0.075, 0.07]),
                ([-0.09, 0.0, 0.2], [0.08, 0.075, 0.07]),
            ],
        ),
        (
            Some(2),
            [0.0, 0.0, 0.29],
            I,
            vec![x, y],
            vec![
                ([0.0, 0.0, 0.04], [0.05, 0.05, 0.06]),
                ([0.0, 0.015, 0.16], [0.075, 0.09, 0.11]),
            ],
        ),
    ];
    for sign in [1.0, -1.0] {
        let base = parts.len();
        parts.push((
            Some(2),
            [0.17 * sign, 0.0, 0.23],
            rot_y(150.0 * sign),
            vec![x, y, z],
            vec![
                ([0.0, 0.0, 0.07], [0.045, 0.048, 0.09]),
                ([0.0, 0.0, 0.2], [0.038, 0.042, 0.09]),
            ],
        ));
        parts.push((
            Some(base),
            [0.0, 0.0, 0.29],
            I,
            vec![x],
            vec![
                ([0.0, 0.0, 0.07], [0.036, 0.04, 0.09]),
                ([0.0, 0.0, 0.19], [0.028, 0.032, 0.08]),
            ],
        ));
        parts.push((
            Some(base + 1),
            [0.0, 0.0, 0.26],
            I,
            vec![x],
            vec![
                ([0.0, 0.0, 0.06], [0.022, 0.045, 0.06]),
                ([0.0, 0.0, 0.13], [0.016, 0.04, 0.04]),
            ],
        ));
        parts.push((
            Some(0),
            [0.09 * sign, 0.0, -0.05],
            rot_y(180.0),
            vec![x, y, z],
            vec![
                ([0.0, 0.0, 0.1], [0.075, 0.08, 0.12]),
                ([0.0, 0.0, 0.3], [0.055, 0.058, 0.12]),
            ],
        ));
        parts.push((
            Some(base + 3),
            [0.0, 0.0, 0.43],
            I,
            vec![x],
            vec![
                ([0.0, 0.0, 0.1], [0.05, 0.055, 0.12]),
                ([0.0, 0.0, 0.29], [0.038, 0.04, 0.1]),
            ],
        ));
        parts.push((
            Some(base + 4),
            [0.0, 0.0, 0.42],
            [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]],
            vec![x],
            vec![
                ([0.0, -0.05, 0.02], [0.04, 0.035, 0.06]),
                ([0.0, -0.06, 0.12], [0.045, 0.03, 0.07]),
            ],
        ));
    }
    let skin = (2f64.ln() / 2.0).sqrt();
    let mut balls = Vec::new();
    let specs = parts
        .into_iter()
        .enumerate()
        .map(|(b, (parent, offset, rest, axes, part_balls))| {
            for (centre, semi) in part_balls {
                balls.push(Metaball {
                    part: b,
                    centre,
                    radii: semi.map(|s| s / skin),
                });
            }
            PartSpec {
                parent,
                offset,
                rest,
                axes,
            }
        })
        .collect();
    Skeleton::new(specs, balls).unwrap()
}

fn observations(skeleton: &Skeleton, motion: &[f64], shape: &[f64]) -> Observations {
    let mut rng = ChaCha8Rng::seed_from_u64(6);
    let field = Field::new(skeleton, skeleton.pose(shape, motion).unwrap());
    // A point on a lone ball's skin, |q| = 0.589: close to the model's skin.
    let on_skin = |rng: &mut ChaCha8Rng| {
        let ball = &field.balls[rng.random_range(0..field.balls.len())];
        let u: Vector3<f64> = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        )
        .normalize();
        let local = ball.centre.component_mul(&ball.scale)
            + (0.589 * u).component_mul(&ball.radii.component_mul(&ball.scale));
        ball.origin + ball.rotation * local
    };
    let points: Vec<[f64; 3]> = (0..50_000).map(|_| on_skin(&mut rng).into()).collect();
    let mut origins = Vec::new();
    let mut directions = Vec::new();
    for camera in 0..8 {
        let angle = camera as f64 * std::f64::consts::TAU / 8.0;
        let centre = Vector3::new(3.5 * angle.cos(), 3.5 * angle.sin(), 1.3);
        for _ in 0..2000 {
            let target = on_skin(&mut rng);
            origins.push(centre.into());
            directions.push((target - centre).normalize().into());
        }
    }
    Observations {
        frames: 1,
        point_frame: vec![0; points.len()],
        points,
        ray_frame: vec![0; origins.len()],
        origins,
        directions,
        sigma: [0.05, 0.05, 0.01],
        log_epsilon: Some(0.01),
        ..Default::default()
    }
}

fn body(c: &mut Criterion) {
    let skeleton = human();
    let mut motion = vec![0.0; skeleton.n_motion];
    motion[2] = 0.95;
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for m in motion.iter_mut().skip(6) {
        *m = rng.random_range(-0.3..0.3);
    }
    let shape = vec![1.0; skeleton.n_shape()];
    let obs = observations(&skeleton, &motion, &shape);
    let lower = vec![-10.0; skeleton.n_motion];
    let upper = vec![10.0; skeleton.n_motion];
    let options = FitOptions {
        lm: LmOptions::default(),
        fit_shape: true,
        outlier_distance: None,
    };
    let mut body = problem(&skeleton, &obs, &shape, (&lower, &upper), &options).unwrap();
    let (frames, m, s) = body.dims();
    let mut normal = ArrowNormal::new(frames, m, s);
    let mut solver = ArrowSolver::new(frames, m, s).unwrap();
    let mut x = motion.clone();
    x.extend_from_slice(&shape);
    // The fit assigns balls to observations before its first iteration.
    body.refresh(&x, 0).unwrap();

    let mut group = c.benchmark_group("body_lm");
    group.sample_size(10);
    group.bench_function("linearize_50k_points_16k_rays", |b| {
        b.iter(|| black_box(body.linearize(black_box(&x), &mut normal).unwrap()))
    });
    body.linearize(&x, &mut normal).unwrap();
    group.bench_function("solve_damped_arrowhead", |b| {
        b.iter(|| black_box(solver.solve(black_box(&normal), 1e-3).unwrap()))
    });
    group.bench_function("cost_50k_points_16k_rays", |b| {
        b.iter(|| black_box(body.cost(black_box(&x)).unwrap()))
    });
    group.bench_function("iteration_50k_points_16k_rays", |b| {
        b.iter(|| {
            body.linearize(&x, &mut normal).unwrap();
            let step = solver.solve(&normal, 1e-3).unwrap();
            let mut trial: Vec<f64> = x.iter().zip(&step).map(|(a, d)| a + d).collect();
            body.project(&mut trial);
            black_box(body.cost(&trial).unwrap())
        })
    });
    group.finish();
}

criterion_group!(benches, body);
criterion_main!(benches);
